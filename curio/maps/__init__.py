"""The map library and map management from the dashboard (issue 13, item 3; docs/maps.md)."""
