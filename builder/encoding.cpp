// Vertex attribute encodings shared with the shaders' decoders (octahedral normals, half floats), and the
// bookkeeping shared by the DAG builder and the page decoder.
#include "tessera/builder.h"

#include <algorithm>
#include <cmath>
#include <cstring>

namespace tessera {

void append_cluster(BuiltMesh& mesh, const Cluster& c) {
    if (c.level == 0) {
        ++mesh.leafClusters;
        mesh.leafVertices = c.vertexOffset + c.vertexCount;
        mesh.leafTriangles = c.triangleOffset + c.triangleCount;
    }
    if (mesh.levels.size() <= c.level) mesh.levels.resize(c.level + 1);
    LevelStats& level = mesh.levels[c.level];
    ++level.clusters;
    level.triangles += c.triangleCount;
    level.maxError = std::max(level.maxError, c.lodError);
    mesh.clusters.push_back(c);
}

uint32_t encode_octahedral(float x, float y, float z) {
    const float l1 = std::fabs(x) + std::fabs(y) + std::fabs(z);
    float u = x / l1, v = y / l1;
    if (z < 0) {
        const float pu = (1 - std::fabs(v)) * (u >= 0 ? 1.0f : -1.0f);
        const float pv = (1 - std::fabs(u)) * (v >= 0 ? 1.0f : -1.0f);
        u = pu;
        v = pv;
    }
    auto snorm = [](float f) { return uint32_t(uint16_t(int16_t(std::lround(std::clamp(f, -1.0f, 1.0f) * 32767.0f)))); };
    return snorm(u) | (snorm(v) << 16);
}

std::array<float, 3> decode_octahedral(uint32_t packed) {
    auto unorm = [](uint32_t bits) { return std::max(float(int16_t(uint16_t(bits))) / 32767.0f, -1.0f); };
    float u = unorm(packed & 0xffff), v = unorm(packed >> 16);
    const float z = 1 - std::fabs(u) - std::fabs(v);
    if (z < 0) {
        const float pu = (1 - std::fabs(v)) * (u >= 0 ? 1.0f : -1.0f);
        const float pv = (1 - std::fabs(u)) * (v >= 0 ? 1.0f : -1.0f);
        u = pu;
        v = pv;
    }
    const float len = std::sqrt(u * u + v * v + z * z);
    return {u / len, v / len, z / len};
}

uint16_t float_to_half(float value) {
    uint32_t bits;
    std::memcpy(&bits, &value, 4);
    const uint32_t sign = (bits >> 16) & 0x8000;
    const int32_t exponent = int32_t((bits >> 23) & 0xff) - 127 + 15;
    uint32_t mantissa = bits & 0x7fffff;
    if (((bits >> 23) & 0xff) == 0xff) return uint16_t(sign | 0x7c00 | (mantissa ? 0x200 : 0));  // inf / nan
    if (exponent >= 31) return uint16_t(sign | 0x7c00);
    if (exponent <= 0) {
        if (exponent < -10) return uint16_t(sign);
        mantissa |= 0x800000;
        const uint32_t shift = uint32_t(14 - exponent);
        uint32_t half = mantissa >> shift;
        if ((mantissa >> (shift - 1)) & 1) ++half;  // round half up
        return uint16_t(sign | half);
    }
    uint32_t half = sign | (uint32_t(exponent) << 10) | (mantissa >> 13);
    if (mantissa & 0x1000) ++half;  // round half up (may carry into the exponent, which is correct)
    return uint16_t(half);
}

}  // namespace tessera
