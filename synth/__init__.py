"""Synthetic scenes rendered with Mitsuba 3, with exactly known cameras."""
