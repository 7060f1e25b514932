"""Files: panoramas in (``images``; photo spheres padded by ``photo_sphere``, HDR files developed by
``tone_mapping``, dual-fisheye files refused by ``dual_fisheye``), layouts out as JSON (``export``), meshes
(``mesh``) and other tools' formats (``formats``, read back by ``formats_read`` as ``layout_corners.LayoutCorners``),
atomically (``files``)."""
