"""Print jobs: preparing them through the pipeline and following them on the station."""
