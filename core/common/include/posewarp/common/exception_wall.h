// The exception wall: every public entry point of a stage that calls third-party code (ITK, VTK, CGAL, CHOLMOD,
// nlohmann, the standard library's allocator) runs its body through guarded(), so an exception becomes a Status
// with context and nothing reaches std::terminate. posewarp's own code reports errors as Status; exceptions here
// are always someone else's.
#pragma once

#include <exception>
#include <new>
#include <string>
#include <string_view>
#include <utility>

#include "posewarp/common/result.h"

namespace posewarp {

// Runs `body` (returning Status or Result<T>). std::bad_alloc becomes RESOURCE_EXHAUSTED, any other exception
// INTERNAL; both messages start with `doing` ("reading 'ct.nii.gz'") so the user knows which step failed, and the
// first says what to do: `advice` ("lower the voxel budget or use coarser mesh sizes"), or free memory and use less.
// No stage catches std::bad_alloc itself; the only other catches turn a library's own error into its meaning (ITK's
// ExceptionObject on a damaged file, nlohmann's type errors, a mesh reader's exception: the user's input is bad).
template <typename Body>
auto guarded(std::string_view doing, std::string_view advice, Body&& body) -> decltype(body()) {
  try {
    return body();
  } catch (const std::bad_alloc&) {
    return resource_exhausted_error("out of memory " + std::string(doing) + "; " + std::string(advice));
  } catch (const std::exception& error) {
    return internal_error("unexpected failure " + std::string(doing) + ": " + error.what());
  } catch (...) {
    return internal_error("unexpected failure " + std::string(doing) + " (an exception of unknown type)");
  }
}

inline constexpr std::string_view kFreeMemoryAdvice = "free memory, or use a smaller volume or coarser settings";

template <typename Body>
auto guarded(std::string_view doing, Body&& body) -> decltype(body()) {
  return guarded(doing, kFreeMemoryAdvice, std::forward<Body>(body));
}

}  // namespace posewarp
