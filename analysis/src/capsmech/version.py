"""The package's version, in a module of its own: files capsmech writes record it, and the
modules that write them import it from here (importing it from the package would make every
one of them depend on the whole public API)."""

__version__ = "0.1.0"
