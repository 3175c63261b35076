#pragma once
// The C++ object behind `ProgressSink` in the bridge `src/embed/bridge.rs`: it
// lends the host's progress callback to Rust for the duration of one call.
// Included by the cxx-generated code, so it must not include the public
// header (whose `Progress` is the same `std::function` type).

#include <functional>

#include "rust/cxx.h"

namespace subdfit::ffi {

class ProgressSink {
 public:
  using Callback = std::function<bool(const char* stage, double fraction)>;

  // `callback` may be empty (no reporting, no cancellation); it must outlive
  // the sink, which lives on the stack of one API call.
  explicit ProgressSink(const Callback& callback) : callback_(callback) {}

  // Returns the callback's answer (false = cancel). Rust serialises calls
  // (`embed::Progress`), so the callback never runs on two threads at once.
  // An exception from the callback propagates: the bridge declares this
  // function `-> Result<bool>`, so cxx turns it into a Rust `Err`.
  bool report(rust::Str stage, double fraction) const;

 private:
  const Callback& callback_;
};

}  // namespace subdfit::ffi
