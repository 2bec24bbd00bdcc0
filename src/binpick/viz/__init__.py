"""Plots people look at rather than read (matplotlib, written as PNG)."""
