"""Where many runs execute: a local process pool or a Dask cluster, whose workers die with their parent."""
