"""The demos, one per paper family: ``sml_cudam`` (``jaxanom demo``), ``mmf`` (``jaxanom demo mmf``),
``offroad`` (``jaxanom demo offroad``)."""
