"""Pictures of a layout: reprojected onto the panorama (``overlay``), the floor plan (``plan``), the panorama
textured onto the room (``room_texture``), its 3D viewer (``viewer``) and the index of a folder of results
(``gallery``)."""
