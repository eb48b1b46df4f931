"""bench/sections.py, which bench/run calls to write docs/benchmarks.md: a partial run replaces only the sections of
the scripts it ran, and text written by hand after a section (outside its markers) is kept by every run."""

import subprocess
import sys

from quad_common.paths import REPO_ROOT

SECTIONS = REPO_ROOT / 'bench' / 'sections.py'


def write(tmp_path, sections: dict, keep_others: bool):
    out_dir = tmp_path / 'new'
    out_dir.mkdir(exist_ok=True)
    for name, body in sections.items():
        (out_dir / f'{name}.md').write_text(body)
    args = [sys.executable, str(SECTIONS), str(tmp_path / 'benchmarks.md'), str(out_dir), 'DATE', 'MACHINE']
    subprocess.run(args + (['--keep-others'] if keep_others else []), check=True)
    for path in out_dir.iterdir():
        path.unlink()
    return (tmp_path / 'benchmarks.md').read_text()


def test_a_partial_run_replaces_its_section_and_keeps_the_others_and_every_hand_note(tmp_path):
    write(tmp_path, {'bench_a': 'A one', 'bench_b': 'B one'}, keep_others=False)
    doc = tmp_path / 'benchmarks.md'
    text = doc.read_text()
    doc.write_text(text.replace('<!-- /bench_a -->\n', '<!-- /bench_a -->\n\n### A note by hand\n\nkept\n')
                   .replace('<!-- /bench_b -->\n', '<!-- /bench_b -->\n\nB\'s note\n'))

    text = write(tmp_path, {'bench_a': 'A two'}, keep_others=True)

    assert 'A two' in text and 'A one' not in text and 'B one' in text
    assert text.index('A two') < text.index('### A note by hand') < text.index('kept') < text.index('B one')
    assert text.index('B one') < text.index("B's note")

    text = write(tmp_path, {'bench_a': 'A three', 'bench_b': 'B two'}, keep_others=False)

    assert text.count('### A note by hand') == 1 and text.count("B's note") == 1
    assert text.index('A three') < text.index('### A note by hand') < text.index('B two') < text.index("B's note")
