"""fleet_sim package."""
