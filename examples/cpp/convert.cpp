// convert INPUT OUTPUT.obj [--tolerance T] [--faces N] [--threads N]
//         [--displacement-reconstruction bilinear|bspline]
//         [--report REPORT.json] [--cancel-at STAGE:FRACTION] [--self-test WHAT]
// Reads a mesh with OpenMesh, converts it with a progress bar on stderr and
// writes the control mesh. Any error: the message on stderr, then its kind
// (`convert: error kind: option`), exit status 1.
// (--self-test runs one of the library's test hooks instead of converting.)

#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <string>

#include "mesh_io.h"

// subdfit::ErrorKind in words.
static const char* kind_name(subdfit::ErrorKind k) {
  switch (k) {
    case subdfit::ErrorKind::Input: return "input";
    case subdfit::ErrorKind::Option: return "option";
    case subdfit::ErrorKind::Numerical: return "numerical";
    case subdfit::ErrorKind::Internal: return "internal";
    case subdfit::ErrorKind::Cancelled: return "cancelled";
  }
  return "unknown";
}

int main(int argc, char** argv) {
  if (argc < 3) {
    std::fprintf(stderr, "usage: %s INPUT OUTPUT.obj [--tolerance T] [--faces N]\n", argv[0]);
    return 2;
  }
  subdfit::Options options;
  options.source_name = argv[1];
  const char* self_test = nullptr;
  // --cancel-at STAGE:F says stop at the first report of STAGE at F or more
  // (how a DCC's cancel button behaves, at a reproducible moment).
  std::string cancel_stage;
  double cancel_at = 2.0;  // never
  const char* report_path = nullptr;
  for (int i = 3; i + 1 < argc; i += 2) {
    if (!std::strcmp(argv[i], "--tolerance")) options.tolerance = std::atof(argv[i + 1]);
    else if (!std::strcmp(argv[i], "--faces")) options.target_faces = std::atoi(argv[i + 1]);
    else if (!std::strcmp(argv[i], "--self-test")) self_test = argv[i + 1];
    else if (!std::strcmp(argv[i], "--threads")) options.threads = std::atoi(argv[i + 1]);
    else if (!std::strcmp(argv[i], "--displacement-reconstruction"))
      options.displacement_reconstruction = !std::strcmp(argv[i + 1], "bspline")
                                                ? subdfit::DisplacementReconstruction::BSpline
                                                : subdfit::DisplacementReconstruction::Bilinear;
    else if (!std::strcmp(argv[i], "--report")) report_path = argv[i + 1];
    else if (!std::strcmp(argv[i], "--cancel-at")) {
      const std::string a = argv[i + 1];
      const std::size_t colon = a.rfind(':');
      cancel_stage = colon == std::string::npos ? "" : a.substr(0, colon);
      cancel_at = std::atof(a.c_str() + (colon == std::string::npos ? 0 : colon + 1));
    }
  }
  std::string last_stage;
  using Clock = std::chrono::steady_clock;
  Clock::time_point cancelled_at{};
  const subdfit::Progress bar = [&](const char* stage, double fraction) {
    if (stage != last_stage) {
      if (!last_stage.empty()) std::fputc('\n', stderr);
      last_stage = stage;
    }
    const int width = 30, done = static_cast<int>(fraction * width + 0.5);
    std::fprintf(stderr, "\r%-12s [%s%s] %3d%%", stage, std::string(done, '#').c_str(),
                 std::string(width - done, ' ').c_str(), static_cast<int>(fraction * 100 + 0.5));
    if (cancelled_at != Clock::time_point{}) return false;
    if (fraction < cancel_at || (!cancel_stage.empty() && cancel_stage != stage)) return true;
    cancelled_at = Clock::now();
    return false;
  };
  try {
    if (self_test) {
      subdfit::detail::self_test(self_test, bar);
      return 0;
    }
    const example::FlatMesh mesh = example::read_mesh(argv[1]);
    const subdfit::Result r = subdfit::convert(mesh.view(), options, bar);
    std::fputc('\n', stderr);
    example::write_control_obj(argv[2], r.control);
    if (report_path) example::write_file(report_path, r.report_json);
    if (const double* rms = r.metric("limit.rms_permille"))
      std::fprintf(stderr, "RMS limit distance: %g permille\n", *rms);
  } catch (const std::exception& e) {
    if (!last_stage.empty()) std::fputc('\n', stderr);
    std::fprintf(stderr, "convert: error: %s\n", e.what());
    if (const auto* se = dynamic_cast<const subdfit::Error*>(&e))
      std::fprintf(stderr, "convert: error kind: %s\n", kind_name(se->kind()));
    if (cancelled_at != Clock::time_point{})
      std::fprintf(stderr, "cancel latency: %.1f ms\n",
                   std::chrono::duration<double, std::milli>(Clock::now() - cancelled_at).count());
    return 1;
  }
  return 0;
}
