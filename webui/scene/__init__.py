"""Artifacts -> viser scene nodes (paths mirror the data model: /world/cams/{cam}, /world/persons/{pid}/...)."""
