//! Procedural bin scenes, depth rendering by ray casting, and dataset generation
