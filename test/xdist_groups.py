"""pytest-xdist groups for test-graph's --dist loadgroup (the hook is imported by conftest.py)."""

import pytest

SHARED_SCOPES = ('class', 'module', 'package')


@pytest.hookimpl(wrapper=True)
def pytest_collection_modifyitems(config, items):
    """The tests of a file that use a fixture wider than one test (a module-scoped flight, an identified model) form
    one xdist_group, so pytest-xdist's --dist loadgroup runs them on one worker and that fixture is set up once; every
    other test is scheduled on its own. The group is marked before xdist's hook, which reads it; after that hook, any
    group it did not put in the nodeid is put there (see _in_its_group)."""
    grouped = []
    for item in items:
        if any(defs[-1].scope in SHARED_SCOPES for defs in item._fixtureinfo.name2fixturedefs.values()):
            group = item.nodeid.split('::')[0]
            item.add_marker(pytest.mark.xdist_group(group))
            grouped.append((item, group))
    result = yield
    if getattr(config.option, 'loadgroup', False):      # set on a pytest-xdist worker under --dist loadgroup
        for item, group in grouped:
            _in_its_group(item, group)
    return result


def _in_its_group(item, group):
    """loadgroup schedules by the nodeid's suffix '@group'. pytest-xdist 3.8 appends it by setting item._nodeid,
    which pytest 9 no longer reads (its nodeid is str(item._id)): without this every test of a group went to any
    worker and each worker set the group's module fixture up again (two 130 s rotorpy flights in one run)."""
    if not item.nodeid.endswith(f'@{group}'):
        item._id = type(item._id).parse(f'{item.nodeid}@{group}')
    assert item.nodeid.endswith(f'@{group}'), item.nodeid
