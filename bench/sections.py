"""Writes docs/benchmarks.md from the sections bench/run collected (one file per benchmark script).

Each section sits between `<!-- bench_NAME -->` and `<!-- /bench_NAME -->` with the date and machine it was
measured on, so `bench/run NAME` replaces that one section and keeps the others (--keep-others). Text written by
hand after a section's end marker (notes on a run, a measurement no script makes) belongs to that section and is
kept wherever it moves, by every run: only the script's own output is replaced.
"""

import argparse
import re
from pathlib import Path

HEADER = '# Benchmarks\n\nWritten by `bench/run`. Peers run in the same run as ours, side by side.\n'
SECTION = re.compile(r'<!-- (bench_\w+) -->\n.*?<!-- /\1 -->\n', re.S)


def existing_sections(path: Path) -> tuple[dict, dict]:
    """({name: the section, markers included}, {name: the hand-written text after it, up to the next section})."""
    text = path.read_text() if path.exists() else ''
    matches = list(SECTION.finditer(text))
    sections = {m.group(1): m.group(0) for m in matches}
    ends = [m.start() for m in matches[1:]] + [len(text)]
    notes = {m.group(1): text[m.end():end].strip('\n') for m, end in zip(matches, ends)}
    return sections, {name: note for name, note in notes.items() if note}


def main():
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument('out', type=Path)
    parser.add_argument('sections', type=Path, help='folder of bench_NAME.md files')
    parser.add_argument('date')
    parser.add_argument('machine')
    parser.add_argument('--keep-others', action='store_true')
    args = parser.parse_args()
    sections, notes = existing_sections(args.out)
    if not args.keep_others:
        sections = {}
    for path in sorted(args.sections.glob('bench_*.md')):
        body = path.read_text().strip()
        sections[path.stem] = (f'<!-- {path.stem} -->\n_Measured {args.date} on {args.machine}._\n\n'
                               f'{body}\n<!-- /{path.stem} -->\n')
    body = '\n'.join(sections[name] + (f'\n{notes[name]}\n' if name in notes else '')
                      for name in sorted(sections)) if sections else '_No benchmarks yet._\n'
    args.out.write_text(f'{HEADER}\n{body}')


if __name__ == '__main__':
    main()
