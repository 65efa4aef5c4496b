// esim_py (uzh-rpg/rpg_vid2e) fed from memory: the same EventSimulator, its own
// imageCallback, with frames handed over as uint8 arrays instead of decoded from PNG.
// The per-frame work is that of EventSimulator::generateFromStampedImageSequence minus
// cv::imread: convertTo(CV_32F, 1/255), cv::log(img + log_eps), imageCallback; the result is
// the same (N, 4) matrix of x, y, t, polarity.
// imageCallback is private in esim.h; this file opens it for the one function below (the
// headers esim.h includes come first, so only esim.h itself is read with the define).
#include <algorithm>
#include <string>
#include <vector>

#include <boost/filesystem.hpp>
#include <Eigen/Core>
#include <opencv2/core.hpp>
#include <opencv2/core/core.hpp>
#include <pybind11/eigen.h>
#include <pybind11/numpy.h>
#include <pybind11/pybind11.h>
#include <pybind11/stl.h>

#define private public
#include <esim.h>
#undef private

namespace py = pybind11;

static Eigen::MatrixXd generate_from_frames(
    EventSimulator& sim, py::array_t<uint8_t, py::array::c_style> frames,
    std::vector<double> timestamps) {
  if (frames.ndim() != 3 || static_cast<size_t>(frames.shape(0)) != timestamps.size())
    throw std::runtime_error("frames must be (N, H, W) uint8 with N timestamps");
  const int h = static_cast<int>(frames.shape(1)), w = static_cast<int>(frames.shape(2));
  std::vector<Event> events;
  for (size_t i = 0; i < timestamps.size(); ++i) {
    cv::Mat u8(h, w, CV_8U, const_cast<uint8_t*>(frames.data(i, 0, 0)));
    cv::Mat img, log_img;
    u8.convertTo(img, CV_32F, 1.0 / 255);
    cv::log(img + sim.log_eps_, log_img);
    sim.imageCallback(log_img, timestamps[i], events);
  }
  sim.is_initialized_ = false;
  return sim.vec_to_eigen_matrix(events);
}

PYBIND11_MODULE(esim_py_memory, m) {
  m.doc() = "esim_py's EventSimulator with frames from memory (benchmark baseline)";
  py::class_<EventSimulator>(m, "EventSimulator")
      .def(py::init<float, float, float, float, bool>());
  m.def("generate_from_frames", &generate_from_frames,
        "Events (N, 4: x, y, t, p) of uint8 frames (N, H, W) at timestamps (s)");
}
