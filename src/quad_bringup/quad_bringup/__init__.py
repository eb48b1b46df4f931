"""quadflight's user-facing package: the command and what it runs, a sub-package per job."""

__version__ = '0.1.0'
