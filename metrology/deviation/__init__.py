"""Deviation: the signed normal deviations of the scan from the (registered) nominal, the
trim-edge deviations and the size error they give, and the vertices left unscored."""
