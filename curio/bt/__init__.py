"""The behaviour tree (py_trees), the path manager and the tour guide."""
