// Internal to the builder: cuts of the cluster DAG chosen by error and triangle count (trimming, fallback mesh).
#pragma once

#include <cstddef>
#include <cstdint>
#include <vector>

namespace tessera {

// A cluster, as far as cuts are concerned.
struct DagNode {
    float lodError;       // its group's error (0 at level 0)
    float parentError;    // its parent group's error; infinity for roots
    uint32_t level;
    uint32_t triangles;
    int32_t madeBy;       // the group that made it (-1 at level 0)
    int32_t parentGroup;  // the group made from it (-1 for roots)
};

// The source (every level-0 cluster), or for a threshold t every cluster with lodError <= t < parentError. Siblings
// share both errors, so each group is wholly refined or wholly collapsed: every such cut is crack-free.
struct DagCut {
    bool source = true;
    float threshold = 0;
    bool contains(const DagNode& n) const { return source ? n.level == 0 : n.lodError <= threshold && threshold < n.parentError; }
    // In the cut or coarser than it (the part of the DAG a trimmed mesh keeps).
    bool keeps(const DagNode& n) const { return source || threshold < n.parentError; }
};

struct CutStats {
    uint64_t triangles = 0;
    float error = 0;  // the largest lodError in the cut
};
CutStats measure(const std::vector<DagNode>& nodes, const DagCut& cut);

// The first cut, from fine to coarse, whose error is at least minError and whose triangles are at most maxTriangles;
// the coarsest (the roots) if none is. Both measures grow monotonically coarser, so the search is a bisection.
DagCut choose_cut(const std::vector<DagNode>& nodes, double minError, double maxTriangles);

DagCut coarser(const DagCut& a, const DagCut& b);

// Trimming the DAG to a cut: the cut becomes level 0, what is finer goes, what is coarser keeps its groups.
struct TrimPlan {
    std::vector<int32_t> level;  // per node: its new level, -1 when dropped
    std::vector<int32_t> group;  // per old group: its new index, -1 when dropped
    uint32_t groups = 0;
};
// `nodes` in creation order (every group after its children).
TrimPlan plan_trim(const std::vector<DagNode>& nodes, size_t groupCount, const DagCut& cut);

}  // namespace tessera
