"""Controllers shipped with third-party env packages, made into `--collector.type=callable` experts."""
