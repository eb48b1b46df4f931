"""YAML files read with errors that name the file and the problem."""

import os

import yaml


def load_yaml(path) -> dict:
    path = os.fspath(path)
    try:
        with open(path) as f:
            data = yaml.safe_load(f)
    except FileNotFoundError:
        raise ValueError(f'{path}: file not found') from None
    except yaml.YAMLError as exc:
        raise ValueError(f'{path}: not valid YAML: {exc}') from None
    if not isinstance(data, dict):
        raise ValueError(f'{path}: expected a mapping at the top level, got {type(data).__name__}')
    return data
