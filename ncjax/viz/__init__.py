"""Pictures of a layout: reprojected onto the panorama (``overlay``) and the floor plan (``plan``)."""
