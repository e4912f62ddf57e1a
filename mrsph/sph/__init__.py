"""The SPH core: kernels, particles, levels, grids, neighbours, walls, density, forces, integration."""
