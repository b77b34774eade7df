"""The optimisation, owned by the host: Adam and its schedules, and the adaptive density control."""
