"""GNSS models: time scales, frames, broadcast orbits and clocks, atmosphere, geometry."""
