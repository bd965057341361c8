"""Implementation of facewarp. Nothing here is public API; import from :mod:`facewarp`."""
