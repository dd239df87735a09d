// Helpers shared by the C++ test suites.
#pragma once

#include "tessera/builder.h"

#include <array>
#include <vector>

// A polygon mesh view over arrays the caller keeps alive.
inline tessera::MeshView polygon_view(std::string name, std::span<const float> points, std::span<const int32_t> counts,
                                      std::span<const int32_t> indices) {
    tessera::MeshView v;
    v.name = std::move(name);
    v.points = points;
    v.faceVertexCounts = counts;
    v.faceVertexIndices = indices;
    return v;
}

// An n x n grid of quads over (n + 1)^2 points, point (x, y) at `point(x, y)` (an array of 3 floats), appended to the
// arrays; `corner(x, y, cx, cy)` is called for each corner (cx, cy) of face (x, y) in order ((x, y), (x + 1, y),
// (x + 1, y + 1), (x, y + 1)), where a face-varying primvar is written.
template <typename Point, typename Corner>
void quad_grid(int n, Point point, Corner corner, std::vector<float>& points, std::vector<int32_t>& counts, std::vector<int32_t>& indices) {
    const int first = int(points.size() / 3);
    for (int y = 0; y <= n; ++y)
        for (int x = 0; x <= n; ++x) {
            const auto p = point(x, y);
            points.insert(points.end(), {float(p[0]), float(p[1]), float(p[2])});
        }
    for (int y = 0; y < n; ++y)
        for (int x = 0; x < n; ++x) {
            counts.push_back(4);
            const int corners[4][2] = {{x, y}, {x + 1, y}, {x + 1, y + 1}, {x, y + 1}};
            for (const auto& c : corners) {
                indices.push_back(first + c[1] * (n + 1) + c[0]);
                corner(x, y, c[0], c[1]);
            }
        }
}
