"""Every import of every package is declared in its package.xml with a rosdep key that exists, so that
`rosdep install --from-paths src` on a ROS 2 Jazzy machine installs what the nodes import.

Keys are ROS package names (resolved from the distribution), our own packages, or the system keys of
ros/rosdistro's rosdep/python.yaml and base.yaml listed in SYSTEM_KEYS (checked there by hand; a new third-party
import needs its key added here after checking it exists)."""

import ast
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
PACKAGES = sorted(p.name for p in (ROOT / 'src').iterdir() if (p / 'package.xml').is_file())
# Python top-level module -> rosdep key (ros/rosdistro rosdep/python.yaml; each resolves on Ubuntu noble and on
# Debian bookworm, Jazzy's Tier 3 platform: python3-ruamel.yaml, say, has Debian entries up to buster only)
SYSTEM_KEYS = {
    'numpy': 'python3-numpy',
    'scipy': 'python3-scipy',
    'yaml': 'python3-yaml',
    'matplotlib': 'python3-matplotlib',
    'pymavlink': 'python3-pymavlink-pip',
    'rosbags': 'python3-rosbags-pip',
    'numba': 'python3-numba',
    'mpl_toolkits': 'python3-matplotlib',
    'pytest': 'python3-pytest',
}
# imported only for an optional feature, with no rosdep key (the import's ImportError names what to install)
OPTIONAL_WITHOUT_KEY = {'dask': 'sweep / tune --scheduler: pip install "dask[distributed]"'}
# ROS 2 Jazzy packages the nodes import (rosdep resolves a ROS package name to ros-jazzy-<name>)
ROS_PACKAGES = {'rclpy', 'launch', 'launch_ros', 'ament_index_python', 'builtin_interfaces', 'rcl_interfaces',
                'std_msgs', 'std_srvs', 'geometry_msgs', 'nav_msgs', 'sensor_msgs', 'trajectory_msgs',
                'diagnostic_msgs', 'visualization_msgs', 'rosgraph_msgs', 'tf2_msgs'}


def declared(package: str) -> dict[str, set[str]]:
    root = ET.parse(ROOT / 'src' / package / 'package.xml').getroot()
    deps = {}
    for tag in ('depend', 'exec_depend', 'test_depend', 'build_depend'):
        deps[tag] = {e.text.strip() for e in root.findall(tag)}
    return deps


def imports(paths) -> set[str]:
    """Top-level modules imported anywhere in `paths` (also inside functions and try blocks), minus stdlib."""
    found = set()
    for path in paths:
        for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
            if isinstance(node, ast.Import):
                found |= {a.name.split('.')[0] for a in node.names}
            elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
                found.add(node.module.split('.')[0])
    return {m for m in found if m not in sys.stdlib_module_names and m != 'setuptools'}


def key(module: str) -> str:
    return SYSTEM_KEYS.get(module, module)


@pytest.mark.parametrize('package', PACKAGES)
def test_every_import_is_declared_with_a_valid_key(package):
    pkg = ROOT / 'src' / package
    runtime = imports([*pkg.glob(f'{package}/**/*.py'), *pkg.glob('launch/*.py')]) - set(OPTIONAL_WITHOUT_KEY)
    local = {p.stem for p in pkg.glob('test/**/*.py')}   # the tests' own helper modules (conftest, ...)
    tests = imports(pkg.glob('test/**/*.py')) - runtime - local
    deps = declared(package)
    run_deps = deps['depend'] | deps['exec_depend']
    missing = sorted(key(m) for m in runtime - {package} if key(m) not in run_deps)
    assert not missing, f'{package}/package.xml: exec_depend missing for {missing}'
    missing_tests = sorted(key(m) for m in tests - {package} if key(m) not in run_deps | deps['test_depend'])
    assert not missing_tests, f'{package}/package.xml: test_depend missing for {missing_tests}'
    valid = set(PACKAGES) | ROS_PACKAGES | set(SYSTEM_KEYS.values())
    unknown = sorted(k for k in set().union(*deps.values()) if k not in valid)
    assert not unknown, f'{package}/package.xml: {unknown} are not rosdep keys (nor packages of this workspace)'


def _module_imports() -> dict[str, set[str]]:
    """Our module -> our modules it imports (at the top or inside a function: a lazy import is an arrow too)."""
    paths = {'.'.join(p.relative_to(ROOT / 'src').parts[1:])[:-3].removesuffix('.__init__'): p
             for p in (ROOT / 'src').glob('*/*/**/*.py') if p.relative_to(ROOT / 'src').parts[1] != 'test'}
    arrows = {}
    for name, path in paths.items():
        found = set()
        for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
            if isinstance(node, ast.Import):
                found |= {a.name for a in node.names}
            elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
                found |= {node.module} | {f'{node.module}.{a.name}' for a in node.names}
        arrows[name] = (found & paths.keys()) - {name}
    return arrows


def test_no_import_cycle_between_modules():
    """Every import arrow points one way (depth-first search for a back edge); a cycle is named in full."""
    arrows, done, path = _module_imports(), set(), []

    def visit(module):
        if module in path:
            raise AssertionError('import cycle: ' + ' -> '.join(path[path.index(module):] + [module]))
        if module not in done:
            path.append(module)
            for target in sorted(arrows[module]):
                visit(target)
            path.pop()
            done.add(module)

    for module in sorted(arrows):
        visit(module)


@pytest.mark.parametrize('package', PACKAGES)
def test_optional_imports_without_a_key_are_named_in_package_xml(package):
    """An import with no rosdep key (OPTIONAL_WITHOUT_KEY) is named in a comment of its package.xml, with how to
    install it, so that a packager sees it."""
    pkg = ROOT / 'src' / package
    used = imports([*pkg.glob(f'{package}/**/*.py')]) & set(OPTIONAL_WITHOUT_KEY)
    text = (pkg / 'package.xml').read_text()
    for module in used:
        assert f'optional, no rosdep key: {module}' in text, f'{package}/package.xml does not name {module}'


def cross_links(root: Path, importer: str, provider: str) -> list[str]:
    """Where a file under root/importer/ reaches into root/provider/: an import of a module that lives there (a
    top-level name of one of its .py files) or a sys.path entry naming that folder. What both need lives in a
    package (quad_bringup.emulated.vehicle_graph, mission_flight, offline_chain, twin_check, peer_venv,
    rotorpy_peer)."""
    provided = {p.stem for p in (root / provider).rglob('*.py')}
    found = []
    for path in sorted((root / importer).rglob('*.py')):
        tree = ast.parse(path.read_text(), str(path))
        for node in ast.walk(tree):
            if isinstance(node, ast.Import):
                names = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
                names = [node.module]
            else:
                names = []
            found += [f'{path.relative_to(root)}:{node.lineno}: imports {n}' for n in names
                      if n.split('.')[0] in provided]
            if isinstance(node, ast.stmt) and not isinstance(node, (ast.FunctionDef, ast.ClassDef, ast.With, ast.If,
                                                                    ast.For, ast.Try, ast.AsyncFunctionDef)):
                segment = ast.get_source_segment(path.read_text(), node) or ''
                strings = {c.value.strip('/') for c in ast.walk(node)
                           if isinstance(c, ast.Constant) and isinstance(c.value, str)}
                if 'sys.path' in segment and any(s == provider or s.endswith('/' + provider) for s in strings):
                    found.append(f'{path.relative_to(root)}:{node.lineno}: puts {provider}/ on sys.path')
    return found


@pytest.mark.parametrize('importer, provider', [('bench', 'test'), ('test', 'bench')])
def test_bench_and_test_do_not_import_each_other(importer, provider):
    assert cross_links(ROOT, importer, provider) == []


# quad_bringup's sub-packages by job, lowest first (README's layout row, docs/design.md)
BRINGUP_LAYERS = (('limits', 'checks', 'pools'), ('recording',), ('analysis',), ('offline',), ('running',),
                  ('experiments',), ('cli', 'commands'), ('emulated', 'peers'))


def test_quad_bringup_sub_packages_import_downward_only():
    """A module of quad_bringup imports from its own sub-package or one below, never one above, so each job can be
    read and tested with what it stands on; a new sub-package gets its place in BRINGUP_LAYERS."""
    rank = {room: i for i, rooms in enumerate(BRINGUP_LAYERS) for room in rooms}
    arrows = {m: t for m, t in _module_imports().items() if m.startswith('quad_bringup.')}
    unplaced = sorted({m.split('.')[1] for m in arrows} - set(rank))
    assert not unplaced, f'quad_bringup sub-packages without a place in BRINGUP_LAYERS: {unplaced}'
    upward = sorted(f'{module} -> {target}' for module, targets in arrows.items() for target in targets
                    if target.startswith('quad_bringup.') and target.split('.')[1] in rank
                    and rank[target.split('.')[1]] > rank[module.split('.')[1]])
    assert not upward, f'quad_bringup imports upward: {upward}'


def test_quad_common_core_imports_no_rclpy_at_import():
    """quad_common's core (every module outside quad_common/ros) imports neither rclpy at its top nor
    quad_common.ros anywhere: the offline tools and the report import it without ROS; a helper that needs rclpy at
    import belongs in quad_common/ros."""
    package = ROOT / 'src' / 'quad_common' / 'quad_common'
    found = []
    for path in sorted(p for p in package.glob('**/*.py') if p.relative_to(package).parts[0] != 'ros'):
        tree = ast.parse(path.read_text(), filename=str(path))
        top = [n for n in tree.body if isinstance(n, (ast.Import, ast.ImportFrom))]
        for node in ast.walk(tree):
            names = ([a.name for a in node.names] if isinstance(node, ast.Import) else
                     [node.module or ''] + [f'{node.module}.{a.name}' for a in node.names]
                     if isinstance(node, ast.ImportFrom) else [])
            if any(n == 'quad_common.ros' or n.startswith('quad_common.ros.') for n in names) or (
                    node in top and any(n.split('.')[0] == 'rclpy' for n in names)):
                found.append(f'{path.relative_to(package)}:{node.lineno}')
    assert not found, f'quad_common core imports rclpy or quad_common.ros: {found}'
