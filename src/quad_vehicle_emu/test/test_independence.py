"""The emulator must be a second reading of the protocol: it may not use the bridge's code, and quad_sim (the
physics) may not depend on the bridge or on pymavlink."""

import ast
import subprocess
import sys
from pathlib import Path

PKG = Path(__file__).resolve().parent.parent
SRC = PKG.parent


def _imports(package_dir: Path) -> set[str]:
    names = set()
    for path in package_dir.rglob('*.py'):
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            if isinstance(node, ast.Import):
                names.update(a.name.split('.')[0] for a in node.names)
            elif isinstance(node, ast.ImportFrom) and node.module:
                names.add(node.module.split('.')[0])
    return names


def test_emulator_sources_do_not_import_the_bridge():
    imported = _imports(PKG / 'quad_vehicle_emu')
    assert 'quad_bridge' not in imported
    assert {'quad_common', 'quad_sim', 'pymavlink'} <= imported


def test_importing_the_emulator_loads_no_bridge_module():
    code = ('import sys, quad_vehicle_emu.mavlink_vehicle; '
            'print(sorted(m for m in sys.modules if m.startswith("quad_bridge")))')
    out = subprocess.run([sys.executable, '-c', code], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == '[]'


def test_quad_sim_depends_on_neither_the_bridge_nor_pymavlink():
    imported = _imports(SRC / 'quad_sim' / 'quad_sim')
    assert not imported & {'quad_bridge', 'pymavlink', 'quad_vehicle_emu'}
    manifest = (SRC / 'quad_sim' / 'package.xml').read_text()
    assert 'quad_bridge' not in manifest and 'pymavlink' not in manifest
