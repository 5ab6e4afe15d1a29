"""Browser review and annotation app (viser). Importing this package is light: no torch, no viser."""
