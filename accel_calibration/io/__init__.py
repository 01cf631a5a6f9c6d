"""Files: calibration YAML (versioned, atomic), CSV pose tables, report figures. Imports core only."""
