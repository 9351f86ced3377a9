"""The .bg grammar, shipped inside the wheel as ``bondc.grammar``."""
