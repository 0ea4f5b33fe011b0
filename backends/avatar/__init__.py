"""The mesh avatar the render backend draws: geometry, skinning, shading, scene, headless GL."""
