"""Dense, slow, obviously correct reference implementations used as test oracles."""
