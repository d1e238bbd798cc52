"""Sample buffers, tone mapping and image files."""
