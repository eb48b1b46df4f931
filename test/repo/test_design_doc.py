"""docs/design.md names every module of the packages and every launch file, and only what exists: every file
(`pkg/module.py`, `launch/x.launch.py`, `test_x.py`), every module a package row of its table lists, and every
`module.name` / `Class.method` it quotes (read with ast, no import)."""

import ast
import re
from functools import cache
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
DESIGN = ROOT / 'docs' / 'design.md'
PACKAGES = sorted(p.name for p in (ROOT / 'src').iterdir() if (p / 'package.xml').is_file())
SOURCES = sorted(p for p in (ROOT / 'src').glob('*/*/**/*.py') if p.relative_to(ROOT / 'src').parts[1] != 'test')
TESTS = {p.name for p in ROOT.glob('test/**/*.py')} | {p.name for p in (ROOT / 'src').glob('*/test/*.py')}


def quoted(text: str) -> list[str]:
    return re.findall(r'`([^`\s]+)`', text)


@cache
def names_in(path: Path) -> dict[str, set[str]]:
    """Top-level names of a module -> for a class, the names defined in its body (else an empty set)."""
    out = {}
    for node in ast.parse(path.read_text()).body:
        if isinstance(node, (ast.FunctionDef, ast.ClassDef, ast.AsyncFunctionDef)):
            out[node.name] = {n.name for n in node.body if isinstance(n, (ast.FunctionDef, ast.AsyncFunctionDef))} | {
                t.id for n in node.body if isinstance(n, (ast.Assign, ast.AnnAssign))
                for t in (n.targets if isinstance(n, ast.Assign) else [n.target]) if isinstance(t, ast.Name)}
        elif isinstance(node, (ast.Assign, ast.AnnAssign)):
            for t in node.targets if isinstance(node, ast.Assign) else [node.target]:
                for name in ast.walk(t):
                    if isinstance(name, ast.Name):
                        out[name.id] = set()
        elif isinstance(node, ast.ImportFrom):
            out.update({a.asname or a.name: set() for a in node.names})
    return out


def module_file(dotted: str) -> Path | None:
    """src/<pkg>/<pkg>/a/b.py of 'pkg.a.b', or None."""
    parts = dotted.split('.')
    path = ROOT / 'src' / parts[0] / Path(*parts) if parts[0] in PACKAGES else None
    return path.with_suffix('.py') if path is not None and path.with_suffix('.py').is_file() else None


def file_exists(token: str, package: str | None) -> bool:
    name = token
    if name.startswith('test_'):
        return name in TESTS
    if name.startswith(('test/', 'bench/', 'scripts/')):
        return (ROOT / name).is_file()
    if name.startswith('quad_'):       # pkg/module.py or quad_x/launch/...
        pkg, _, rest = name.partition('/')
        return (ROOT / 'src' / pkg / pkg / rest).is_file() or (ROOT / 'src' / pkg / rest).is_file()
    if name.startswith('launch/'):
        return (ROOT / 'src' / 'quad_bringup' / name).is_file()
    packages = [package] if package else PACKAGES
    return any((ROOT / 'src' / p / p / name).is_file() for p in packages)


def name_exists(token: str) -> bool:
    """'pkg.module[.name]', 'module.name' (a module of src) or 'Class.member' (a class of src)."""
    parts = token.split('.')
    for i in range(len(parts), 0, -1):   # the longest module prefix of a package path
        path = module_file('.'.join(parts[:i]))
        if path is not None:
            rest = parts[i:]
            return not rest or (rest[0] in names_in(path) and (len(rest) == 1 or rest[1] in names_in(path)[rest[0]]))
    if len(parts) != 2:
        return False
    first, second = parts
    modules = [p for p in SOURCES if p.stem == first]
    if modules:
        return any(second in names_in(p) for p in modules)
    classes = [names_in(p)[first] for p in SOURCES if first in names_in(p) and names_in(p)[first]]
    return any(second in members for members in classes)


def test_every_module_file_and_name_in_design_md_exists():
    missing = []
    for line in DESIGN.read_text().splitlines():
        row = re.match(r'\| `(quad_[a-z_]+)` \|', line)
        package = row.group(1) if row else None
        for token in quoted(line):
            token = token.split('(')[0].rstrip(',.;:')   # `ControlLoop.tick(t_k)`: the name
            if token.endswith('.py'):
                ok = file_exists(token, package)
            elif re.fullmatch(r'[A-Za-z_][A-Za-z0-9_]*(\.[A-Za-z_][A-Za-z0-9_]*)+', token):
                ok = name_exists(token)
            else:
                continue
            if not ok:
                missing.append(f'{token} ({package or "text"})')
    assert not missing, f'docs/design.md names what the tree does not have: {missing}'


def test_every_package_has_a_row():
    rows = set(re.findall(r'^\| `(quad_[a-z_]+)` \|', DESIGN.read_text(), flags=re.M))
    assert rows == set(PACKAGES), f'docs/design.md package table: {sorted(rows ^ set(PACKAGES))}'


def test_every_module_and_launch_file_is_named():
    """The other way round: a module (src/<pkg>/<pkg>/**.py but __init__) or launch file design.md does not name
    is a room the next maintainer cannot find on the map."""
    tokens = {t.split('(')[0].rstrip(',.;:') for t in quoted(DESIGN.read_text())}
    named = {t.rsplit('/', 1)[-1] for t in tokens if t.endswith('.py')}
    unnamed = [str(p.relative_to(ROOT)) for p in SOURCES + sorted((ROOT / 'src').glob('*/launch/*.py'))
               if p.name != '__init__.py' and p.name not in named]
    assert not unnamed, f'docs/design.md does not name: {unnamed}'


def test_readme_layout_names_every_quad_bringup_module_by_job():
    """quad_bringup holds five jobs in one package: README's layout row is its map, so it names every module
    (and every subcommand module) there."""
    row = next(line for line in (ROOT / 'README.md').read_text().splitlines()
               if line.startswith('| `src/quad_bringup` |'))
    named = set(quoted(row))
    package = ROOT / 'src' / 'quad_bringup' / 'quad_bringup'
    unnamed = [str(p.relative_to(package)) for p in sorted(package.glob('**/*.py'))
               if p.name != '__init__.py' and p.stem not in named]
    assert not unnamed, f"README.md's layout row of src/quad_bringup does not name: {unnamed}"
