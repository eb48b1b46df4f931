"""Launch files, checked statically (`launch` is not installable here): every Node(package, executable)
they start is a console script of that package's setup.py, and every params file they name exists
under config/ (installed to share/quad_bringup/config).

Convention for launch files: params files are named by string literals relative to config/,
e.g. config('control.yaml') or 'vehicles/px4_quad.yaml'.
"""

import ast
from pathlib import Path

import pytest

PKG = Path(__file__).resolve().parents[1]
SRC = PKG.parent
CONFIG = PKG / 'config'
LAUNCH_FILES = sorted((PKG / 'launch').glob('*.py'))


def console_scripts(package: str) -> dict[str, Path]:
    """{executable: module file} of the `name = module:function` entry points of src/<package>/setup.py."""
    tree = ast.parse((SRC / package / 'setup.py').read_text())
    scripts = {}
    for node in ast.walk(tree):
        if isinstance(node, ast.Constant) and isinstance(node.value, str) and ' = ' in node.value and ':' in node.value:
            name, target = (s.strip() for s in node.value.split('=', 1))
            scripts[name] = SRC / package / (target.split(':')[0].replace('.', '/') + '.py')
    return scripts


def launched_nodes(tree):
    for node in ast.walk(tree):
        if isinstance(node, ast.Call) and getattr(node.func, 'id', getattr(node.func, 'attr', None)) == 'Node':
            kw = {k.arg: k.value for k in node.keywords}
            yield (kw['package'].value if isinstance(kw.get('package'), ast.Constant) else None,
                   kw['executable'].value if isinstance(kw.get('executable'), ast.Constant) else None)


def yaml_literals(tree):
    return [n.value for n in ast.walk(tree)
            if isinstance(n, ast.Constant) and isinstance(n.value, str) and n.value.endswith(('.yaml', '.yml'))]


def test_there_is_a_sim_launch_file():
    assert PKG / 'launch' / 'sim.launch.py' in LAUNCH_FILES


@pytest.mark.parametrize('path', LAUNCH_FILES, ids=[p.name for p in LAUNCH_FILES])
def test_launch_file_names_existing_executables_and_params(path):
    tree = ast.parse(path.read_text(), filename=str(path))
    nodes = list(launched_nodes(tree))
    assert nodes, f'{path.name}: starts no Node'
    for package, executable in nodes:
        assert package and executable, f'{path.name}: Node package/executable must be literals'
        assert (SRC / package / 'setup.py').exists(), f'{path.name}: package {package} does not exist'
        scripts = console_scripts(package)
        assert executable in scripts, f'{path.name}: {package} has no executable {executable} (setup.py)'
        assert scripts[executable].exists(), \
            f'{path.name}: {package}/{executable} names {scripts[executable]}, which does not exist'
    for name in yaml_literals(tree):
        assert (CONFIG / name).is_file(), f'{path.name}: params file config/{name} does not exist'


def test_config_is_installed_with_the_launch_files():
    setup = (PKG / 'setup.py').read_text()
    assert "glob('launch/*.py')" in setup and 'config_files()' in setup
    assert CONFIG.resolve() == (SRC.parent / 'config').resolve()
