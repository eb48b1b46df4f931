"""Every code block of README.md and docs/*.md is fenced on lines of its own: a fence that shares a line with text
swallows the prose after it into the block (or the block into the prose) when rendered."""

from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
PAGES = [ROOT / 'README.md', *sorted((ROOT / 'docs').glob('*.md'))]


@pytest.mark.parametrize('page', PAGES, ids=lambda p: str(p.relative_to(ROOT)))
def test_code_fences_stand_on_their_own_lines(page):
    inside = False
    for number, line in enumerate(page.read_text().splitlines(), 1):
        if '```' not in line:
            continue
        where = f'{page.relative_to(ROOT)}:{number}: {line.strip()[:80]!r}'
        assert line.lstrip().startswith('```'), f'a fence after text on one line: {where}'
        if inside:
            assert line.strip() == '```', f'a closing fence with text after it: {where}'
        inside = not inside
    assert not inside, f'{page.relative_to(ROOT)}: a code block is never closed'
