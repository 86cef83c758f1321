"""What a capture will render, decided before the first frame: the settings asked for (``settings``), the
scene checked against them (``planning``, ``notes``, ``world``) and the plan of every frame, the same on
every machine of a farm (``frame_plan``)."""
