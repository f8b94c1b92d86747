//! Ranking and checking grasp configurations into executable picks
