"""Host-side visualisation: the self-contained HTML episode player (``viz.player``)."""
