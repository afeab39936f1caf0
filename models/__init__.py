"""Model data shipped with configpose: MJCF models (rover.xml, quadcopter.xml) and TOML files
(sensor configurations, paths, noise models, receiver layouts). Installed as the package
``configpose_models`` (see pyproject.toml); code finds it through
:data:`estimator.model_files.MODELS_DIR`, never by importing this package directly."""
