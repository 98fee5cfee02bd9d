"""Framers (events -> frames) and frame rendering; importing this package registers the framers."""
