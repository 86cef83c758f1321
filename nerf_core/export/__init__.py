"""The trained scene as geometry: a coloured triangle mesh (``mesh``), density and colour grids
(``volume``), and how far a mesh lies from the scene's own surfaces (``score``)."""
