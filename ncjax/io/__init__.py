"""Files: panoramas in (``images``) and levelled (``align``), layouts out as JSON (``export``) and meshes
(``mesh``), atomically (``files``)."""
