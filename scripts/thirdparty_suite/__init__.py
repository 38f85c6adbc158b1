"""The third-party truth suite: raw probing sessions whose truth comes from FElupe (quadratic
tetrahedra on gmsh meshes), not from softcap. See scripts/thirdparty-suite and docs/thirdparty.md."""
