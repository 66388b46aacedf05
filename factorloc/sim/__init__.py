"""A simulated indoor world: floor plans, textured walls, rendered panoramas, camera images and depth clouds."""
