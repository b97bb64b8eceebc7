"""Where the package's shipped files (config/) are, installed or in a checkout."""

from __future__ import annotations

from pathlib import Path
import sys

PACKAGE = 'memo_ros'


def share_dir() -> Path:
    """Return the package's share directory: ament index, else the venv prefix, else checkout."""
    try:
        from ament_index_python.packages import get_package_share_directory

        path = Path(get_package_share_directory(PACKAGE))
        if (path / 'config').is_dir():
            return path
    except Exception:  # noqa: BLE001 - not on an ament install, or package not indexed
        pass
    checkout = Path(__file__).resolve().parent.parent
    if (checkout / 'config').is_dir() and (checkout / 'package.xml').is_file():
        return checkout
    prefix = Path(sys.prefix) / 'share' / PACKAGE
    if (prefix / 'config').is_dir():
        return prefix
    raise FileNotFoundError('cannot find the memo_ros share directory (config/)')


def config_path(name: str) -> Path:
    """Path of a file shipped in config/."""
    path = share_dir() / 'config' / name
    if not path.is_file():
        raise FileNotFoundError(f'no shipped config file {name!r} in {path.parent}')
    return path
