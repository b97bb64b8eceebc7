"""docs/design.md maps every numbered equation of both papers to a function that exists."""

from __future__ import annotations

import importlib
from pathlib import Path
import re

import pytest

ROOT = Path(__file__).resolve().parent.parent
SEEDS = ROOT.parent / 'shared' / 'seeds'
PAPERS = {
    'Kakadiaris & Metaxas': '001_923bd046e6d0da67.txt',
    'Rohr': '000_b4bbd61a7f20583e.txt',
}
# an equation number: \tag{N}, '\quad (N)' or '\qquad (N)' closing a formula, or '(N)' on a line
# alone
NUMBERED = re.compile(r'\\tag\{(\d+)\}|\\q?quad \((\d+)\)|^\s*\((\d+)\)\s*$', re.MULTILINE)
ROW = re.compile(r'^\| (\d+) \| [^|]+ \| (.+) \|$', re.MULTILINE)


def _tables() -> dict[str, dict[int, str]]:
    """Return each paper's equation table of docs/design.md: number -> function cell."""
    text = (ROOT / 'docs' / 'design.md').read_text(encoding='utf-8')
    tables = {}
    for paper in PAPERS:
        start = text.index(f'## {paper}')
        end = text.find('\n## ', start + 1)
        section = text[start : end if end > 0 else None]
        tables[paper] = {int(n): cell for n, cell in ROW.findall(section)}
    return tables


def _resolve(dotted: str) -> object:
    """Import the longest module prefix of ``dotted`` and walk the rest as attributes."""
    parts = dotted.split('.')
    for k in range(len(parts), 0, -1):
        try:
            target = importlib.import_module('.'.join(parts[:k]))
        except ImportError:
            continue
        for name in parts[k:]:
            target = getattr(target, name)
        return target
    raise ImportError(dotted)


@pytest.mark.parametrize('paper', list(PAPERS))
def test_every_numbered_equation_of_the_paper_is_in_the_table(paper):
    path = SEEDS / PAPERS[paper]
    if not path.is_file():
        pytest.skip(f'{path} not available')
    numbers = {int(next(g for g in m if g)) for m in NUMBERED.findall(path.read_text())}
    assert numbers, 'no equation numbers found: the pattern no longer matches the paper'
    table = _tables()[paper]
    assert numbers == set(range(1, max(numbers) + 1)), sorted(numbers)
    assert set(table) == numbers, (sorted(numbers - set(table)), sorted(set(table) - numbers))


@pytest.mark.parametrize('paper', list(PAPERS))
def test_every_function_named_exists_and_is_callable(paper):
    for number, cell in _tables()[paper].items():
        names = re.findall(r'`([\w.]+)`', cell)
        if not names:
            assert cell.startswith('not implemented:'), (number, cell)
            continue
        assert len(names) == 1, (number, cell)
        assert callable(_resolve(names[0])), (number, names[0])


def _anchors(path: Path) -> set[str]:
    """Return the GitHub-style anchors of a markdown file's headings."""
    found = set()
    for line in path.read_text(encoding='utf-8').splitlines():
        if line.startswith('#'):
            title = re.sub(r'[^\w\- ]', '', line.lstrip('#').strip().lower())
            found.add(title.replace(' ', '-'))
    return found


def test_every_relative_link_of_the_readme_and_docs_resolves():
    broken = []
    for page in [ROOT / 'README.md', *sorted((ROOT / 'docs').glob('*.md'))]:
        for link in re.findall(r'\]\(([^)\s]+)\)', page.read_text(encoding='utf-8')):
            if link.startswith(('http://', 'https://')):
                continue
            target, _, anchor = link.partition('#')
            path = (page.parent / target) if target else page
            if not path.exists():
                broken.append(f'{page.name}: {link} (no file)')
            elif anchor and path.suffix == '.md' and anchor not in _anchors(path):
                broken.append(f'{page.name}: {link} (no heading)')
    assert not broken, '\n'.join(broken)


def test_the_readme_stays_one_page():
    assert len((ROOT / 'README.md').read_text(encoding='utf-8').splitlines()) <= 300


@pytest.mark.parametrize('node', ['contour_node', 'selector_node', 'tracker_node', 'walker_node'])
def test_each_node_parameter_table_in_the_docs_is_the_declared_one(node):
    from memo_ros.ros.params import markdown_table

    table = markdown_table(importlib.import_module(f'memo_ros.nodes.{node}').PARAMS)
    section = (ROOT / 'docs' / 'nodes.md').read_text().split(f'\n## {node}')[1].split('\n## ')[0]
    documented = '\n'.join(line for line in section.splitlines() if line.startswith('| `'))
    declared = '\n'.join(table.splitlines()[2:])
    assert declared in documented, (
        f'docs/nodes.md ## {node}: regenerate its table with memo_ros.ros.params.markdown_table'
    )
