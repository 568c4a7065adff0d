//! Local view cells (SPEC §7): template comparison with a horizontal shift search.
