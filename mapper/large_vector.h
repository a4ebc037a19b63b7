// Storage for the mapper's per-voxel arrays (field parameters, optimiser moments, gradients):
// hundreds of MB that grow with the map. Allocations of 2 MB and more are anonymous mappings
// advised for transparent huge pages, so that growing them commits 2 MB pages instead of 4 KB
// ones. On a virtual machine a 4 KB page fault costs microseconds: zero-filling 128 MB of new
// voxels took 0.5-0.9 s with 4 KB pages and 0.04-0.4 s with huge pages on this kind of host,
// and the mapper grows by tens of MB per keyframe.
#pragma once

#include <sys/mman.h>

#include <cstddef>
#include <cstdint>
#include <new>
#include <vector>

namespace radslam {

template <class T>
struct HugePageAllocator {
  using value_type = T;
  static constexpr size_t kHugePage = size_t{2} << 20;

  HugePageAllocator() = default;
  template <class U>
  HugePageAllocator(const HugePageAllocator<U>&) {}  // NOLINT: allocator rebinding

  T* allocate(size_t n) {
    const size_t bytes = n * sizeof(T);
    if (bytes < kHugePage) return static_cast<T*>(::operator new(bytes));
    // Map one huge page more than needed and unmap the ends, so the block starts on a huge
    // page boundary (madvise applies to whole huge pages only).
    const size_t size = roundUp(bytes);
    void* raw = mmap(nullptr, size + kHugePage, PROT_READ | PROT_WRITE,
                     MAP_PRIVATE | MAP_ANONYMOUS | MAP_NORESERVE, -1, 0);
    if (raw == MAP_FAILED) throw std::bad_alloc();
    const uintptr_t begin = reinterpret_cast<uintptr_t>(raw);
    const uintptr_t aligned = (begin + kHugePage - 1) & ~(kHugePage - 1);
    if (aligned > begin) munmap(raw, aligned - begin);
    const uintptr_t end = begin + size + kHugePage;
    if (end > aligned + size) munmap(reinterpret_cast<void*>(aligned + size), end - aligned - size);
    madvise(reinterpret_cast<void*>(aligned), size, MADV_HUGEPAGE);  // advice: failure is fine
    return reinterpret_cast<T*>(aligned);
  }

  void deallocate(T* p, size_t n) {
    const size_t bytes = n * sizeof(T);
    if (bytes < kHugePage) {
      ::operator delete(p);
    } else {
      munmap(p, roundUp(bytes));
    }
  }

  static size_t roundUp(size_t bytes) { return (bytes + kHugePage - 1) & ~(kHugePage - 1); }
};

template <class T, class U>
bool operator==(const HugePageAllocator<T>&, const HugePageAllocator<U>&) {
  return true;
}
template <class T, class U>
bool operator!=(const HugePageAllocator<T>&, const HugePageAllocator<U>&) {
  return false;
}

template <class T>
using LargeVector = std::vector<T, HugePageAllocator<T>>;

}  // namespace radslam
