//! Experience map (SPEC §8): vertices, odometric links, loop closure and map correction.
