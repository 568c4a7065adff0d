"""Type stubs of the native module (hand-written; keep in sync with crates/hippo_py)."""

__version__: str

class HippoNavError(ValueError): ...
