"""The restrained condition's physics: clamps and supports, the part's linear elasticity
(a tetrahedral model of the solid or the thickened sheet) and the clamped free state."""
