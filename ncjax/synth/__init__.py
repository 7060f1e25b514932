"""Synthetic rooms and their panoramas with exact labels (paper Section 5.1).

- ``rooms``: random Manhattan and Atlanta rooms and a camera inside; ``labels``: their exact labels.
- ``furniture``, ``scene``, ``materials``: furnished, lit scenes with procedural materials;
  ``placement``: rectangles in the plan, packed without overlap.
- ``decor``: the realistic scenes' decor (``SceneConfig(decor=True)``): ceiling lights and panels, decals,
  sunlight, open doors; ``elements``: the scenes' containers.
- ``render``, ``raycast``, ``render_details``: ray-cast non-central panoramas (RGB, depth, semantics).
- ``augment``: photometric and sensor effects; ``dataset``: the dataset folders on disk.
"""
