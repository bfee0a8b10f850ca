"""File formats: one module per format, read (and written) behind :mod:`data_tools.datasets`."""
