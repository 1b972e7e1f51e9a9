// copy_cols: dst[i * dst_stride + dst_col + k] = src[i * src_stride + src_col + k] for rows i < n, k < cols.
// Moves a block of columns between row-major matrices (e.g. the colour MLP's input gradient of the geometric
// features into the density MLP's output gradient).
// Bindings: 0 src (float rows), 1 dst (float rows, written).
// Push:     n, cols, src_stride, src_col, dst_stride, dst_col.
// Threads:  one invocation per (row, column), 256 per group, folded into 2D past 65535 groups.
#version 460
#define WG_SIZE 256
#include "common/index.glsl"
layout(local_size_x = WG_SIZE) in;
layout(std430, binding = 0) readonly buffer Src { float src[]; };
layout(std430, binding = 1) writeonly buffer Dst { float dst[]; };
layout(push_constant) uniform Push { uint n; uint cols; uint src_stride; uint src_col; uint dst_stride; uint dst_col; } pc;

void main() {
    uint e = global_index();
    if (e >= pc.n * pc.cols) return;
    uint i = e / pc.cols, k = e % pc.cols;
    dst[i * pc.dst_stride + pc.dst_col + k] = src[i * pc.src_stride + pc.src_col + k];
}
