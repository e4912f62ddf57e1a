"""The scene: its schema and loading (config), seeding, emitters, refinement criteria, interaction."""
