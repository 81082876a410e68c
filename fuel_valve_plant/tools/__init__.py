"""Plant tools: fuel_valve_datasheet."""
