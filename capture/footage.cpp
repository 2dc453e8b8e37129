// Footage from disk: image sequences and video files through OpenCV's
// imgcodecs and videoio (see capture/footage.h). The only part of capture/
// that links them, so that only `dropfit track` loads the video stack.
#include "capture/footage.h"

#include <fmt/format.h>

#include <algorithm>
#include <cctype>
#include <filesystem>
#include <opencv2/core.hpp>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>
#include <opencv2/videoio.hpp>
#include <opencv2/videoio/registry.hpp>
#include <optional>
#include <utility>

#include "core/error.h"
#include "core/progress.h"

namespace dropfit::capture {

namespace {
std::string lower(std::string s) {
  for (char& ch : s) ch = static_cast<char>(std::tolower(static_cast<unsigned char>(ch)));
  return s;
}
}  // namespace

// ---- Frames from disk -----------------------------------------------------------

namespace {
// The frame number of a stem and the stem with it replaced by '#' (one
// sequence has one pattern); number -1 without digits, -2 when too long.
std::pair<long long, std::string> frame_name_parts(const std::string& stem) {
  const auto digit = [](char c) { return std::isdigit(static_cast<unsigned char>(c)) != 0; };
  std::size_t begin = 0, end = 0;
  // Photron: C001H001S0001000399 -> camera 001, head 001, session 0001, frame 000399.
  if (stem.size() > 13 && stem[0] == 'C' && stem[4] == 'H' && stem[8] == 'S' &&
      std::all_of(stem.begin() + 1, stem.begin() + 4, digit) && std::all_of(stem.begin() + 5, stem.begin() + 8, digit) &&
      std::all_of(stem.begin() + 9, stem.end(), digit)) {
    begin = 13;
    end = stem.size();
  } else {
    end = stem.size();
    while (end > 0 && !digit(stem[end - 1])) --end;
    begin = end;
    while (begin > 0 && digit(stem[begin - 1])) --begin;
  }
  if (begin == end) return {-1, stem};
  const std::string pattern = stem.substr(0, begin) + "#" + stem.substr(end);
  if (end - begin > 15) return {-2, pattern};
  return {std::stoll(stem.substr(begin, end - begin)), pattern};
}
}  // namespace

long long frame_number_of(const std::string& stem) { return frame_name_parts(stem).first; }

FrameSequence list_frame_sequence(const std::string& folder) {
  namespace fs = std::filesystem;
  std::error_code ec;
  if (!fs::is_directory(folder, ec)) throw InputError(folder, 0, 0, "", "no such frames folder");
  struct Entry {
    long long number;
    std::string pattern, path;
  };
  std::vector<Entry> entries;
  for (const auto& de : fs::directory_iterator(folder, ec)) {
    if (!de.is_regular_file()) continue;
    const std::string ext = lower(de.path().extension().string());
    if (ext != ".png" && ext != ".tif" && ext != ".tiff") continue;
    const std::string stem = de.path().stem().string();
    const auto [number, pattern] = frame_name_parts(stem);
    if (number == -1) throw InputError(de.path().string(), 0, 0, "", "frame file name holds no frame number");
    if (number < 0 || number > 1000000)
      throw InputError(de.path().string(), 0, 0, "",
                       "frame number too large (above 1,000,000; every row before it would be kept empty)");
    entries.push_back({number, pattern + ext, de.path().string()});
  }
  if (ec) throw InputError(folder, 0, 0, "", "cannot list the frames folder: " + ec.message());
  if (entries.empty()) throw InputError(folder, 0, 0, "", "no PNG or TIFF frames in the folder");
  for (const auto& e : entries)
    if (e.pattern != entries.front().pattern)
      throw InputError(folder, 0, 0, "",
                       fmt::format("the folder mixes frame sequences ('{}' and '{}'); give one camera's frames",
                                   entries.front().pattern, e.pattern));
  std::sort(entries.begin(), entries.end(), [](const Entry& a, const Entry& b) { return a.number < b.number; });
  FrameSequence seq;
  seq.first_frame = entries.front().number;
  for (std::size_t i = 0; i < entries.size(); ++i) {
    if (i > 0 && entries[i].number == entries[i - 1].number)
      throw InputError(entries[i].path, 0, 0, "",
                       fmt::format("frame number {} appears twice (also {})", entries[i].number, entries[i - 1].path));
    if (i > 0 && entries[i].number != entries[i - 1].number + 1)
      throw InputError(folder, 0, 0, "",
                       fmt::format("frame {} is missing (the sequence jumps from {} to {})",
                                   entries[i - 1].number + 1, entries[i - 1].path, entries[i].path));
    seq.files.push_back(entries[i].path);
  }
  return seq;
}

std::vector<std::string> list_frame_files(const std::string& folder) { return list_frame_sequence(folder).files; }

namespace {

// 8-bit grey from whatever OpenCV decoded; `shift_bits` (for 16-bit data)
// is fixed by the first frame of a sequence when negative on entry.
Image8 to_image8(const cv::Mat& decoded, int& bits, const std::string& where) {
  cv::Mat grey;
  if (decoded.channels() == 3) cv::cvtColor(decoded, grey, cv::COLOR_BGR2GRAY);
  else if (decoded.channels() == 4) cv::cvtColor(decoded, grey, cv::COLOR_BGRA2GRAY);
  else if (decoded.channels() == 1) grey = decoded;
  else throw InputError(where, 0, 0, "", fmt::format("unsupported image with {} channels", decoded.channels()));
  cv::Mat out8;
  if (grey.depth() == CV_8U) {
    out8 = grey;
  } else if (grey.depth() == CV_16U) {
    if (bits < 0) {
      double max_value = 0;
      cv::minMaxLoc(grey, nullptr, &max_value);
      bits = 8;
      while (bits < 16 && max_value > (1 << bits) - 1) ++bits;
    }
    grey.convertTo(out8, CV_8U, 255.0 / ((1 << bits) - 1));
  } else {
    throw InputError(where, 0, 0, "", "unsupported pixel type (8- or 16-bit integer images only)");
  }
  Image8 img;
  img.width = out8.cols;
  img.height = out8.rows;
  img.pixels.resize(static_cast<std::size_t>(img.width) * img.height);
  for (int y = 0; y < img.height; ++y)
    std::copy_n(out8.ptr<std::uint8_t>(y), img.width, img.pixels.data() + static_cast<std::size_t>(y) * img.width);
  return img;
}

cv::Mat decode(const std::string& path) {
  cv::Mat m;
  try {
    m = cv::imread(path, cv::IMREAD_ANYDEPTH | cv::IMREAD_ANYCOLOR);
  } catch (const cv::Exception& e) {
    throw InputError(path, 0, 0, "", "cannot read the image: " + std::string(e.what()));
  }
  if (m.empty()) throw InputError(path, 0, 0, "", "cannot read the image (missing, truncated or not an image)");
  return m;
}

}  // namespace

Image8 read_image8(const std::string& path) {
  int bits = -1;
  return to_image8(decode(path), bits, path);
}

struct FrameSource::Impl {
  std::string path;
  std::vector<std::string> files;  // a sequence
  std::optional<cv::VideoCapture> video;
  int count = -1;
  int first = 0;
  int read = 0;
  int bits = -1;
  int width = 0, height = 0;
};

FrameSource::FrameSource(const std::string& path) : impl_(std::make_unique<Impl>()) {
  namespace fs = std::filesystem;
  impl_->path = path;
  std::error_code ec;
  if (fs::is_directory(path, ec)) {
    FrameSequence seq = list_frame_sequence(path);
    impl_->files = std::move(seq.files);
    impl_->first = static_cast<int>(seq.first_frame);
    impl_->count = static_cast<int>(impl_->files.size());
    return;
  }
  if (!fs::exists(path, ec)) throw InputError(path, 0, 0, "", "no such frames folder or video file");
  impl_->video.emplace();
  bool opened = false;
  // FFmpeg when OpenCV has it (it reads what cameras and labs write; the
  // other backends would take a numbered file name for an image pattern).
  const int backend = cv::videoio_registry::hasBackend(cv::CAP_FFMPEG) ? cv::CAP_FFMPEG : cv::CAP_ANY;
  try {
    opened = impl_->video->open(path, backend);
  } catch (const cv::Exception&) {
    opened = false;
  }
  if (!opened) throw InputError(path, 0, 0, "", "cannot open as a video (and it is not a folder of frames)");
  const double n = impl_->video->get(cv::CAP_PROP_FRAME_COUNT);
  impl_->count = n > 0 ? static_cast<int>(n) : -1;
}

FrameSource::~FrameSource() = default;
FrameSource::FrameSource(FrameSource&&) noexcept = default;
FrameSource& FrameSource::operator=(FrameSource&&) noexcept = default;

int FrameSource::size() const { return impl_->count; }
int FrameSource::first_frame() const { return impl_->first; }
int FrameSource::frames_read() const { return impl_->read; }
const std::string& FrameSource::path() const { return impl_->path; }

bool FrameSource::next(Image8& frame) {
  Impl& m = *impl_;
  std::string where;
  cv::Mat decoded;
  if (!m.video) {
    if (m.read >= static_cast<int>(m.files.size())) return false;
    where = m.files[m.read];
    decoded = decode(where);
  } else {
    where = fmt::format("{} (frame {})", m.path, m.read);
    bool ok = false;
    try {
      ok = m.video->read(decoded);
    } catch (const cv::Exception& e) {
      throw InputError(where, 0, 0, "", "cannot decode the frame: " + std::string(e.what()));
    }
    if (!ok || decoded.empty()) return false;
  }
  frame = to_image8(decoded, m.bits, where);
  if (m.read == 0) {
    m.width = frame.width;
    m.height = frame.height;
  } else if (frame.width != m.width || frame.height != m.height) {
    throw InputError(where, 0, 0, "",
                     fmt::format("frame is {} x {}, earlier frames {} x {}", frame.width, frame.height, m.width, m.height));
  }
  ++m.read;
  return true;
}

TrackingResult track_frames(FrameSource& frames, MarkerTracker& tracker, Progress* progress) {
  Image8 img;
  while (frames.next(img)) {
    tracker.add_frame(img.view());
    if (progress && tracker.n_frames() % 50 == 0) {
      progress->update("track", frames.size() > 0 ? fmt::format("{} frame {}/{}", frames.path(), tracker.n_frames(),
                                                                 frames.size())
                                                   : fmt::format("{} frame {}", frames.path(), tracker.n_frames()));
    }
  }
  if (tracker.n_frames() == 0) throw InputError(frames.path(), 0, 0, "", "no frames");
  if (progress) progress->done();
  return tracker.result();
}


TrackingResult track_footage(FrameSource& frames, const std::string& camera, const std::vector<std::string>& points,
                             std::vector<Seed> seeds, const TrackingOptions& options, Progress* progress) {
  const int first = frames.first_frame();
  for (Seed& s : seeds) {
    if (s.frame < first)
      throw InputError(s.source.empty() ? frames.path() : s.source, s.line, 0, "frame",
                       fmt::format("seed frame {} for {} is before the footage, whose first frame is {} ({})", s.frame,
                                   s.point, first, frames.path()));
    s.frame -= first;
  }
  MarkerTracker tracker(camera, points, std::move(seeds), options);
  return shift_frames(track_frames(frames, tracker, progress), first);
}

}  // namespace dropfit::capture
