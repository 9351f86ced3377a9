"""Analyses of compiled models: linearisation (``linearize``), and more to come."""
