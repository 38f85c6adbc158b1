//! Test-only crate: end-to-end tests of the softcap stage chain on sessions written by the
//! virtual rig (`softcap_synth`). Stages stay independent of each other; only this crate's tests
//! depend on several of them. See `tests/`.
