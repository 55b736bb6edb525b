"""rbx: simulate non-standard (rough) billiards with the strict collision maps of Cox, Feres and Ward."""
__version__ = "0.1.0"
