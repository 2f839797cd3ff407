"""What sonarmap reads at run time, shipped as package data: scenes, sonar presets, the
default model's read-only store and the Foxglove layout (`sonarmap.pipeline.package_data`)."""
