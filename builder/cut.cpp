// Choosing cuts of the cluster DAG by error and triangle count.
#include "cut.h"

#include <algorithm>

namespace tessera {

CutStats measure(const std::vector<DagNode>& nodes, const DagCut& cut) {
    CutStats s;
    for (const DagNode& n : nodes)
        if (cut.contains(n)) {
            s.triangles += n.triangles;
            s.error = std::max(s.error, n.lodError);
        }
    return s;
}

DagCut choose_cut(const std::vector<DagNode>& nodes, double minError, double maxTriangles) {
    // Candidates from fine to coarse: the source, then one cut per distinct group error.
    std::vector<float> thresholds;
    for (const DagNode& n : nodes) thresholds.push_back(n.lodError);
    std::sort(thresholds.begin(), thresholds.end());
    thresholds.erase(std::unique(thresholds.begin(), thresholds.end()), thresholds.end());
    auto candidate = [&](size_t k) { return k == 0 ? DagCut{} : DagCut{false, thresholds[k - 1]}; };
    auto good = [&](size_t k) {
        const CutStats s = measure(nodes, candidate(k));
        return s.error >= minError && double(s.triangles) <= maxTriangles;
    };
    size_t lo = 0, hi = thresholds.size();  // the answer lies in [lo, hi]; hi (the roots) when no candidate is good
    while (lo < hi) {
        const size_t mid = (lo + hi) / 2;
        if (good(mid)) hi = mid;
        else lo = mid + 1;
    }
    return candidate(lo);
}

DagCut coarser(const DagCut& a, const DagCut& b) {
    if (a.source) return b;
    if (b.source) return a;
    return a.threshold >= b.threshold ? a : b;
}

TrimPlan plan_trim(const std::vector<DagNode>& nodes, size_t groupCount, const DagCut& cut) {
    TrimPlan plan;
    plan.level.assign(nodes.size(), -1);
    plan.group.assign(groupCount, -1);
    // A kept cluster above the cut was made by a kept group, whose children are all in the cut or above it: its level
    // is one more than theirs, as when the DAG was built.
    std::vector<int32_t> childLevel(groupCount, 0);
    for (size_t i = 0; i < nodes.size(); ++i) {
        const DagNode& n = nodes[i];
        if (!cut.keeps(n)) continue;
        plan.level[i] = cut.contains(n) ? 0 : childLevel[n.madeBy] + 1;
        if (n.parentGroup >= 0) {
            childLevel[n.parentGroup] = std::max(childLevel[n.parentGroup], plan.level[i]);
            plan.group[n.parentGroup] = 0;  // kept: numbered below
        }
    }
    for (int32_t& g : plan.group)
        if (g == 0) g = int32_t(plan.groups++);
    return plan;
}

}  // namespace tessera
