"""Files: panoramas in (``images``), layouts out as JSON (``export``) and meshes (``mesh``), atomically
(``files``)."""
