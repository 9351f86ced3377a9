"""bondc's version (the package facade and every stage that writes it import it from here)."""

__version__ = "0.1.0"
