"""Independent numpy/torch reference implementations used as test oracles."""
