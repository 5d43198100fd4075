"""Studies: longer measurements built on every floor below (`dc study stability|figures|maps`)."""
