"""Config files are found through the installed share directory (ament index), then a checkout's source tree."""

from pathlib import Path

import pytest

from quad_common import paths


def _install(prefix: Path, files: dict) -> Path:
    """A minimal installed quad_bringup under `prefix`: its ament index marker and share/quad_bringup/..."""
    (prefix / 'share/ament_index/resource_index/packages').mkdir(parents=True)
    (prefix / 'share/ament_index/resource_index/packages/quad_bringup').write_text('')
    for name, text in files.items():
        (prefix / 'share/quad_bringup' / name).parent.mkdir(parents=True, exist_ok=True)
        (prefix / 'share/quad_bringup' / name).write_text(text)
    return prefix


def test_installed_share_directory_is_used_without_a_checkout(tmp_path, monkeypatch):
    prefix = _install(tmp_path / 'install', {'config/vehicles/x.yaml': 'name: x\n'})
    monkeypatch.setenv('AMENT_PREFIX_PATH', str(prefix))
    monkeypatch.setattr(paths, 'REPO_ROOT', tmp_path / 'no_checkout')
    monkeypatch.chdir(tmp_path)
    assert paths.resolve_config('config/vehicles/x.yaml') == prefix / 'share/quad_bringup/config/vehicles/x.yaml'
    with pytest.raises(FileNotFoundError, match=r'config/missing\.yaml: no such file \(looked in .*share'):
        paths.resolve_config('config/missing.yaml')


def test_checkout_source_tree_after_the_share_directory(tmp_path, monkeypatch):
    prefix = _install(tmp_path / 'install', {'config/a.yaml': 'installed\n'})
    checkout = tmp_path / 'checkout'
    for name in ('config/a.yaml', 'config/b.yaml'):
        (checkout / name).parent.mkdir(parents=True, exist_ok=True)
        (checkout / name).write_text('checkout\n')
    monkeypatch.setenv('AMENT_PREFIX_PATH', str(prefix))
    monkeypatch.setattr(paths, 'REPO_ROOT', checkout)
    monkeypatch.chdir(tmp_path)
    assert paths.resolve_config('config/a.yaml').read_text() == 'installed\n'
    assert paths.resolve_config('config/b.yaml').read_text() == 'checkout\n'
    monkeypatch.delenv('AMENT_PREFIX_PATH')          # ./quadflight without a sourced workspace
    assert paths.resolve_config('config/a.yaml').read_text() == 'checkout\n'



def test_with_or_without_config_prefix_from_any_directory(tmp_path, monkeypatch):
    prefix = _install(tmp_path / 'install', {'config/vehicles/x.yaml': 'name: x\n'})
    monkeypatch.setenv('AMENT_PREFIX_PATH', str(prefix))
    monkeypatch.setattr(paths, 'REPO_ROOT', tmp_path / 'no_checkout')
    elsewhere = tmp_path / 'elsewhere'
    elsewhere.mkdir()
    monkeypatch.chdir(elsewhere)
    installed = prefix / 'share/quad_bringup/config/vehicles/x.yaml'
    assert paths.resolve_config('vehicles/x.yaml') == installed == paths.resolve_config('config/vehicles/x.yaml')
    (elsewhere / 'vehicles').mkdir()
    (elsewhere / 'vehicles/x.yaml').write_text('name: mine\n')
    assert paths.resolve_config('vehicles/x.yaml') == elsewhere / 'vehicles/x.yaml'   # the working directory first
    assert paths.resolve_config('vehicles/x.yaml').is_absolute()
    with pytest.raises(FileNotFoundError) as refused:
        paths.resolve_config('vehicles/y.yaml')
    assert str(refused.value) == (f'vehicles/y.yaml: no such file (looked in {elsewhere}/vehicles/y.yaml, '
                                  f'{prefix}/share/quad_bringup/config/vehicles/y.yaml)')


def test_the_cache_folder_is_made_under_xdg_cache_home_else_in_the_temporary_folder(tmp_path, monkeypatch):
    monkeypatch.setenv('XDG_CACHE_HOME', str(tmp_path / 'cache'))
    assert paths.cache_dir() == tmp_path / 'cache' / 'quadflight' and paths.cache_dir().is_dir()
    (tmp_path / 'a_file').write_text('')
    monkeypatch.setenv('XDG_CACHE_HOME', str(tmp_path / 'a_file'))   # cannot hold a folder
    monkeypatch.setattr(paths.tempfile, 'gettempdir', lambda: str(tmp_path / 'tmp'))
    assert paths.cache_dir() == tmp_path / 'tmp' / 'quadflight' and paths.cache_dir().is_dir()
