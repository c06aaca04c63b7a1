// Bindings of the row-mapping kernels (backproject, project, vop, triangulate, binocular_vop):
// N input reals and M output reals per item, flat, and one status per item. The first part of
// each of those kernels in src/engine/gpu/kernels.rs.

@group(0) @binding(0) var<uniform> params: Params;
@group(0) @binding(1) var<storage, read> input: array<real>;
@group(0) @binding(2) var<storage, read_write> output: array<real>;
@group(0) @binding(3) var<storage, read_write> status: array<u32>;
