"""Shared fixtures.

An isolated DDS environment per test and a runner for `memo-ros` in subprocesses; under
pytest-xdist (scripts/test.sh runs two workers), the DDS graph tests one at a time on one worker
beside the CPU-only ones, and an ``exclusive`` marker for tests that need the machine to
themselves.
"""

from __future__ import annotations

import contextlib
import fcntl
import functools
import itertools
import os
from pathlib import Path
import signal
import subprocess
import sys
import tempfile
import threading
import time

import pytest

ROOT = Path(__file__).resolve().parent.parent
CLI_ENTRY = 'import sys; from memo_ros.tools.cli import main; sys.exit(main())'


def memo_ros_cli(*args: object, timeout: float = 120.0) -> subprocess.CompletedProcess:
    """Run `memo-ros ARGS` in a fresh interpreter on this checkout, capturing its output."""
    env = dict(
        os.environ,
        PYTHONPATH=os.pathsep.join(filter(None, [str(ROOT), os.environ.get('PYTHONPATH')])),
    )
    return subprocess.run(
        [sys.executable, '-c', CLI_ENTRY, *map(str, args)],
        env=env,
        capture_output=True,
        text=True,
        timeout=timeout,
    )


def wait_until_recording(recorder: subprocess.Popen, topics, timeout: float = 40.0) -> list[str]:
    """Until a `memo-ros bag record` started with RosEnv.start matched a publisher on each topic.

    Its stderr is read from then on by a thread (and no longer by ``communicate``); the lines read
    are returned and keep growing.
    """
    pipe, recorder.stderr = recorder.stderr, None
    lines: list[str] = []

    def read() -> None:
        with pipe:
            for line in pipe:
                lines.append(line)

    threading.Thread(target=read, daemon=True).start()
    deadline = time.monotonic() + timeout
    while not all(any(line.startswith(f'matched {t} ') for line in lines) for t in topics):
        assert recorder.poll() is None, f'the recorder ended early:\n{"".join(lines)}'
        assert time.monotonic() < deadline, f'the recorder matched nothing on:\n{"".join(lines)}'
        time.sleep(0.1)
    # the reader has matched; the writer's half of the match follows it, but on a loaded machine
    # (CI's two workers and another pytest beside them) 0.5 s was once too short: a node's first 7
    # contours went out before its writer had matched the recorder, and were not recorded
    time.sleep(1.5)
    return lines


def play_when_matched(
    domain_id: int,
    bag,
    topics: list[str],
    outputs: list[str],
    rate: float = 1.0,
    remap: dict[str, str] | None = None,
) -> int:
    """Play ``topics`` of ``bag`` once the nodes report their side of every match.

    Every publisher of what is played (published as ``remap`` says) and every subscriber of the
    nodes' ``outputs`` that the graph shows, at least one each, as the nodes report them on
    /diagnostics: the player's own side and a recorder's are not enough, and on a loaded machine
    a node's side once came more than 1.5 s after them. The messages published.
    """
    from memo_ros.ros.dds import MatchedOnDiagnostics, ros_session
    from memo_ros.tools.bag.play import BagPlayer, PlayOptions

    with ros_session('test_player', domain_id) as (node, executor):
        matched = MatchedOnDiagnostics(node)
        options = PlayOptions(rate=rate, topics=topics, remap=remap or {}, wait_for_subscribers=1)
        with BagPlayer(node, bag, options) as player:

            def missing() -> list[str]:
                return player.unmatched_topics() + matched.missing_in_graph(
                    node, player.topics, outputs
                )

            deadline = time.monotonic() + 40.0
            while missing():
                assert time.monotonic() < deadline, f'not matched: {missing()}'
                executor.spin_once(timeout_sec=0.1)
            published = player.play()
            assert player.flush(), 'the nodes did not acknowledge every message'
    return published


_serial = itertools.count()


DOMAIN_LOCKS = Path(tempfile.gettempdir()) / 'memo_ros_test_domains'
_held: dict[int, int] = {}  # domain id -> open lock file descriptor


def next_domain_id() -> int:
    """Reserve and return a ROS_DOMAIN_ID in 1..100 that no other test run on this host holds.

    Each domain is locked (flock) until ``release_domain_id``, so concurrent suites (a CI job
    beside a developer's run) never share a domain and never see each other's nodes.
    """
    DOMAIN_LOCKS.mkdir(exist_ok=True)
    start = os.getpid() + next(_serial)
    for k in range(100):
        domain_id = 1 + (start + k) % 100
        if domain_id in _held:
            continue
        fd = os.open(DOMAIN_LOCKS / f'{domain_id}.lock', os.O_CREAT | os.O_RDWR, 0o666)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            os.close(fd)
            continue
        _held[domain_id] = fd
        return domain_id
    raise RuntimeError('all ROS domains 1..100 are held by other test runs on this host')


def release_domain_id(domain_id: int) -> None:
    """Give a domain reserved by ``next_domain_id`` back."""
    fd = _held.pop(domain_id, None)
    if fd is not None:
        os.close(fd)  # closing the descriptor drops the lock


class RosEnv(dict):
    """Environment for DDS subprocesses (a dict).

    With helpers that run `memo-ros` in it and clean up.
    """

    def __init__(self, domain_id: int) -> None:
        super().__init__(os.environ)
        self.domain_id = domain_id
        self['ROS_DOMAIN_ID'] = str(domain_id)
        self['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
        self['PYTHONPATH'] = os.pathsep.join(
            [str(ROOT)] + [p for p in [os.environ.get('PYTHONPATH')] if p]
        )
        self['PYTHONUNBUFFERED'] = '1'
        # marks every process of this environment, so ones that outlive it can be found
        self.token = f'{os.getpid()}.{domain_id}.{next(_serial)}'
        self['MEMO_ROS_TEST_ENV'] = self.token
        self.processes: list[subprocess.Popen] = []

    def command(self, *args) -> list[str]:
        """Return the command line that runs `memo-ros ARGS` in this environment."""
        return [sys.executable, '-m', 'memo_ros.tools.cli', *map(str, args)]

    def start(self, *args) -> subprocess.Popen:
        """Start `memo-ros ARGS` in the background (stdout and stderr captured as text)."""
        process = subprocess.Popen(
            self.command(*args),
            env=self,
            cwd=ROOT,
            text=True,
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
        )
        self.processes.append(process)
        return process

    def start_node(self, node: str, *ros_args: str) -> subprocess.Popen:
        """Start ``python -m memo_ros.nodes.NODE --ros-args ROS_ARGS``.

        Stdout and stderr merged, as text.
        """
        process = subprocess.Popen(
            [sys.executable, '-m', f'memo_ros.nodes.{node}', '--ros-args', *map(str, ros_args)],
            env=self,
            cwd=ROOT,
            text=True,
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
        )
        self.processes.append(process)
        return process

    def run(self, *args, timeout: float = 30.0) -> subprocess.CompletedProcess:
        """Run `memo-ros ARGS` to completion."""
        process = self.start(*args)
        try:
            out, err = process.communicate(timeout=timeout)
        except subprocess.TimeoutExpired:
            process.kill()
            out, err = process.communicate()
            pytest.fail(
                f'memo-ros {" ".join(map(str, args))} did not finish in {timeout} s:\n{err}'
            )
        return subprocess.CompletedProcess(process.args, process.returncode, out, err)

    def kill_all(self) -> None:
        """Stop every process started here that still runs, collect its output, free the domain.

        SIGINT first, so a `memo-ros launch` stops the nodes it started in their own sessions
        (a SIGKILL would leave them running, orphaned, on this test's domain); SIGKILL after 10 s.
        """
        running = [p for p in self.processes if p.poll() is None]
        for process in running:
            process.send_signal(signal.SIGINT)
        deadline = time.monotonic() + 10.0
        for process in running:
            try:
                process.wait(max(deadline - time.monotonic(), 0.1))
            except subprocess.TimeoutExpired:
                process.kill()
        for process in self.processes:
            if not (process.stdout and process.stdout.closed):  # not collected by the test already
                process.communicate()
        orphans = self.kill_orphans()
        release_domain_id(self.domain_id)
        assert not orphans, (
            f'processes outlived their launcher on domain {self.domain_id}: {orphans}'
        )

    def kill_orphans(self) -> list[str]:
        """SIGKILL processes of this environment that outlived the ones started here.

        A node orphaned by its launcher would otherwise talk to a later test on the same domain.
        Returns their command lines.
        """
        marker = f'MEMO_ROS_TEST_ENV={self.token}'.encode()
        found = []
        for entry in Path('/proc').glob('[0-9]*'):
            try:
                if marker not in (entry / 'environ').read_bytes().split(b'\0'):
                    continue
                cmdline = (entry / 'cmdline').read_bytes().replace(b'\0', b' ').decode()
                os.kill(int(entry.name), signal.SIGKILL)
            except (OSError, ValueError):
                continue  # gone meanwhile, or not ours to read
            found.append(cmdline.strip())
        return found


@pytest.fixture
def ros_env(monkeypatch) -> RosEnv:
    """Return a fresh DDS domain on localhost.

    For this process (in-test nodes) and for subprocesses.
    """
    env = RosEnv(next_domain_id())
    monkeypatch.setenv('ROS_DOMAIN_ID', str(env.domain_id))
    monkeypatch.setenv('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
    yield env
    env.kill_all()


# --- under pytest-xdist (scripts/test.sh: -n 2 --dist loadscope --no-loadscope-reorder) ---

# Real-time DDS graphs are timing-sensitive: two of them side by side on the 2-core host lost
# frames (contour_node, selector_node, graph_faults failed at load 10). So every module that starts
# DDS processes (a test takes ros_env, or the module makes a RosEnv itself), except the
# LOAD_INDEPENDENT ones, is in one xdist work unit, run one test at a time on one worker; the other
# worker takes the CPU-only and the load-independent modules.
GRAPH_GROUP = 'dds-graph'
# DDS modules whose results do not depend on timing, so they run beside the graph unit: replays
# are paced by the tracker's /memo/processed (memo-ros replay; fuzz and memory score or warm the
# graph that way and send their bad input as fast as it goes), the others run one-shot commands
# or wait for one message with a generous timeout
LOAD_INDEPENDENT = frozenset(
    {
        'test_tracking_bags.py',
        'test_replay.py',
        'test_fuzz.py',
        'test_memory.py',
        'test_cli_errors.py',
        'test_echo.py',
        'test_studio.py',
    }
)
RUN_LOCKS = Path(tempfile.gettempdir()) / 'memo_ros_test_runs'  # flock files of each xdist run
# Within the graph unit the longest modules first (seconds on the CI host, serial), so the
# shorter ones fill in at the end; ``exclusive`` tests (the soak) last of all.
LONGEST_MODULES = (
    'test_graph_faults.py',  # ~180
    'test_tracking_bags.py',  # ~130, paced replays: the first the other worker takes
    'test_contour_node.py',  # ~110
    'test_fuzz.py',  # ~80
    'test_walker_node.py',  # ~60
    'test_multihost.py',  # ~45
    'test_robustness.py',  # ~40
    'test_walking.py',  # ~80, CPU only
)


def pytest_configure(config) -> None:
    if hasattr(config, 'workerinput'):  # an xdist worker: the run's lock files, old ones removed
        RUN_LOCKS.mkdir(exist_ok=True)
        for old in RUN_LOCKS.glob('*.*'):
            with contextlib.suppress(OSError):
                if time.time() - old.stat().st_mtime > 86400:
                    old.unlink()
    config.addinivalue_line(
        'markers',
        'exclusive: under pytest-xdist, run while no other test runs (a real-time soak whose '
        'budget is the whole machine); the other workers wait',
    )


@functools.cache
def _in_graph_unit(module: Path) -> bool:
    """Whether a test module runs real-time DDS graphs.

    It starts DDS processes (a test takes ros_env, or it makes a RosEnv) and is not
    LOAD_INDEPENDENT.
    """
    if module.name in LOAD_INDEPENDENT:
        return False
    text = module.read_text(encoding='utf-8')
    return 'ros_env' in text or 'RosEnv(' in text


def pytest_xdist_make_scheduler(config, log):
    """Under xdist: whole modules per worker, and all DDS graph modules as one unit.

    The DDS graph modules form one work unit (one worker, one test at a time); every other module
    is its own, so that its module fixtures are built once. (xdist's own --dist loadgroup does not
    work with pytest 9: it renames a node attribute pytest no longer reads.)
    """
    from xdist.scheduler import LoadScopeScheduling

    class GraphScheduling(LoadScopeScheduling):
        def _split_scope(self, nodeid: str) -> str:
            module = nodeid.split('::', 1)[0]
            return GRAPH_GROUP if _in_graph_unit(config.rootpath / module) else module

    return GraphScheduling(config, log)


def pytest_collection_modifyitems(config, items) -> None:
    """Under xdist: the order the work units are handed out in (a serial run keeps pytest's).

    The graph unit first, as it takes longest; within it and then among the other modules, the
    longest modules first and ``exclusive`` tests last, where they wait for at most a short test
    on the other worker.
    """
    if not hasattr(config, 'workerinput'):
        return

    def rank(item) -> tuple[int, int]:
        name = item.path.name
        longest = LONGEST_MODULES.index(name) if name in LONGEST_MODULES else len(LONGEST_MODULES)
        if item.get_closest_marker('exclusive'):
            longest = len(LONGEST_MODULES) + 1
        return (0 if _in_graph_unit(item.path) else 1, longest)

    items.sort(key=rank)  # stable: each module keeps its own order


@contextlib.contextmanager
def _run_lock(config, exclusive: bool):
    """Hold this xdist run's test lock: shared for a test, exclusive for an ``exclusive`` one.

    Two flock files make a turnstile: an exclusive test takes the gate, so no new test starts,
    then waits for the running ones to end; a test passes the gate and holds the data lock shared.
    """
    run = config.workerinput['testrunuid']
    gate = os.open(RUN_LOCKS / f'{run}.gate', os.O_CREAT | os.O_RDWR, 0o666)
    data = os.open(RUN_LOCKS / f'{run}.data', os.O_CREAT | os.O_RDWR, 0o666)
    try:
        if exclusive:
            fcntl.flock(gate, fcntl.LOCK_EX)
            fcntl.flock(data, fcntl.LOCK_EX)
        else:
            fcntl.flock(gate, fcntl.LOCK_SH)
            fcntl.flock(data, fcntl.LOCK_SH)
            fcntl.flock(gate, fcntl.LOCK_UN)
        yield
    finally:
        os.close(data)
        os.close(gate)


@pytest.hookimpl(wrapper=True)
def pytest_runtest_protocol(item, nextitem):
    """Under xdist, run each test (its setup and teardown too) inside the run's lock."""
    if not hasattr(item.config, 'workerinput'):
        return (yield)
    with _run_lock(item.config, item.get_closest_marker('exclusive') is not None):
        return (yield)
