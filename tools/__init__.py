"""rmpfusion's scripts: reproductions, tables, benchmarks and demos. A package so that tests and other tools import
them from the repository root (``from tools import bench``); each still runs as a script or with ``python -m
tools.<name>`` from the root."""
