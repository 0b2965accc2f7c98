"""The package's version, in a module of its own: the modules that record it import it from here, not from the
package, whose ``__init__`` may import them in turn."""

__version__ = "0.1.0"
