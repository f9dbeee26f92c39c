"""What several test modules share: hand-built scenes and suites, oracles,
worked-case checkers. Not tests themselves (no ``test_*.py`` here); data files
they read live in ``tests/data``."""
