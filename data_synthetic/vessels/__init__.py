"""Building blocks of :mod:`data_synthetic.vessel_generator` (tree growth, surfaces)."""
