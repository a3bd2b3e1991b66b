"""Task environments. Importing `kitbench` registers them with gymnasium under `kitbench/<Task>-v1`."""
