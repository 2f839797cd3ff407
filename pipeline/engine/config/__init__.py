"""The pipeline config: one YAML, a section per stage, `--set` overrides.

Modules:
    load: the config model built from the stages' sections, loading and overrides.
    validation: one-line validation errors naming `section.field` and its bounds.
    yaml_files: the one bounded YAML loader every file sonarmap reads goes through.
"""
