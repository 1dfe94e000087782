"""Independent, dense, obviously correct reference implementations used as test oracles."""
