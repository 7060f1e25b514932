"""Files: panoramas in (``images``), layouts out as JSON (``export``), meshes (``mesh``) and other tools' formats
(``formats``, read back by ``formats_read`` as ``layout_corners.LayoutCorners``), atomically (``files``)."""
