"""Helpers shared by the test modules of several layers, in one place: test modules import these, never
each other. The folder is on sys.path as `test/` (pyproject's [tool.pytest.ini_options] pythonpath), so a
test imports `helpers.<module>` from any layer folder, under `make test` and `colcon test` alike."""
