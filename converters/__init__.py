"""Source readers: one module per dataset, each turning a source log into a ``nuav2.scene.SceneLog``."""
