"""Inversion: from measured lengths and contours to (a/l, Ca_s) and G_s, per capsule and per batch."""
