"""Input and output: RINEX in (validated xarray datasets), tables out."""
