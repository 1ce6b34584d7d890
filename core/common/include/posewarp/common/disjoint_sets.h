// Disjoint sets over 0 .. n-1 (union-find with path halving): which bones a skeleton's edges join, which vertices
// of a mesh are one component, which vertices of an untangled region are one piece.
#pragma once

#include <cstddef>
#include <cstdint>
#include <numeric>
#include <vector>

namespace posewarp {

class DisjointSets {
 public:
  explicit DisjointSets(int64_t n) : parent_(static_cast<size_t>(n)) { std::iota(parent_.begin(), parent_.end(), 0); }

  // The representative of v's set.
  int64_t find(int64_t v) {
    while (parent_[static_cast<size_t>(v)] != v) {
      v = parent_[static_cast<size_t>(v)] = parent_[static_cast<size_t>(parent_[static_cast<size_t>(v)])];
    }
    return v;
  }

  // Joins the sets of a and b; false when they were one already.
  bool unite(int64_t a, int64_t b) {
    a = find(a);
    b = find(b);
    if (a == b) return false;
    parent_[static_cast<size_t>(b)] = a;
    return true;
  }

 private:
  std::vector<int64_t> parent_;
};

}  // namespace posewarp
