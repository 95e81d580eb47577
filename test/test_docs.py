"""The documentation stays true: generated parameter tables are the generated ones, links between the pages resolve
(files and #anchors), and the README stays short."""
import importlib.util
import re
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parent.parent
PAGES = [REPO / 'README.md'] + sorted(p for p in (REPO / 'doc').glob('*.md') if not p.name.startswith('notes-'))
LINK = re.compile(r'!?\[[^\]]*\]\(([^)\s]+)\)')


def param_table():
    spec = importlib.util.spec_from_file_location('param_table', REPO / 'scripts' / 'param_table.py')
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def slug(heading: str) -> str:
    """GitHub's anchor of a Markdown heading."""
    text = heading.strip().lower()
    text = re.sub(r'[^\w\- ]', '', text)
    return text.replace(' ', '-')


def anchors(page: Path) -> set:
    text = re.sub(r'```.*?```', '', page.read_text(), flags=re.S)
    return {slug(m.group(1)) for m in re.finditer(r'^#+ (.+)$', text, re.M)}


@pytest.mark.parametrize('node', ['map_merge', 'explore', 'fleet_sim'])
def test_parameter_tables_in_the_docs_are_generated(node):
    module = param_table()
    page = module.doc_page(node)
    text = page.read_text()
    assert module.replace_table(text, node) == text, \
        f'{page.name}: parameter table out of date: run scripts/env.sh python scripts/param_table.py --write'
    assert text.count('| `~') >= 10


@pytest.mark.parametrize('page', PAGES, ids=[p.name for p in PAGES])
def test_links_resolve(page):
    for target in LINK.findall(page.read_text()):
        if re.match(r'[a-z]+:', target):    # http:, mailto:
            continue
        path, _, anchor = target.partition('#')
        dest = (page.parent / path).resolve() if path else page
        assert dest.exists(), f'{page.name}: link to missing {target}'
        if anchor:
            assert anchor in anchors(dest), f'{page.name}: no heading #{anchor} in {dest.name}'


def test_readme_is_short_and_keeps_the_two_commands():
    text = (REPO / 'README.md').read_text()
    assert len(text.split()) <= 1500
    head = text.split('\n\n')[1]
    assert 'make demo' in head and 'make test' in head
