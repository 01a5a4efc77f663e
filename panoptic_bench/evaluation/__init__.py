"""Dataset scoring drivers: read a dataset tree, check it, run the metric core, write results."""
