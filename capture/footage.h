#pragma once
// Reading footage: folders of numbered PNG/TIFF frames and video files
// (OpenCV imgcodecs and videoio). Its own library, dropfit_video, used only
// by `dropfit track` and the tracking tests, so that nothing else loads the
// video stack. The tracker itself (capture/tracking.h) takes image views and
// does no I/O.
//
// Frame numbers: the number in a frame file's name is the frame, i.e. the
// row of xypts.csv (docs/formats.md, "Footage"): a sequence
// exported from frame 399 on (frame_00399.png, ...) fills rows from 399.
// The number is the last run of digits in the file's stem, except in the
// Photron naming CxxxHxxxSxxxxNNNNNN (camera, head, session, then the
// frame), where it is the digits after the session's four. A video file
// numbers its frames from 0.
#include <memory>
#include <string>
#include <vector>

#include "capture/tracking.h"

namespace dropfit::capture {

// The frame number a sequence file's stem (name without extension) gives;
// -1 when it holds no digits. Numbers above 1,000,000 are refused by the
// readers below (every row before the first frame is kept, as NaN).
long long frame_number_of(const std::string& stem);

// The image files of a sequence folder (PNG or TIFF), in frame order, and
// the number of the first. Throws dropfit::InputError naming the folder when
// it is missing or holds no frames, when it mixes differently named
// sequences, or when a frame number is skipped or repeated (a missing frame
// would shift every later frame out of step with the other camera).
struct FrameSequence {
  long long first_frame = 0;
  std::vector<std::string> files;
};
FrameSequence list_frame_sequence(const std::string& folder);
// The files alone (list_frame_sequence(folder).files).
std::vector<std::string> list_frame_files(const std::string& folder);

// One image as 8-bit grey (colour converted to luma; 16-bit scaled by its
// bit depth, see FrameSource). Throws dropfit::InputError when unreadable.
Image8 read_image8(const std::string& path);

// One camera's frames, read one at a time: a folder of PNG/TIFF images
// (list_frame_sequence) or a video file OpenCV can open. 16-bit frames are
// scaled to 8 bits by the bit depth seen in the first frame (12-bit data
// stored in 16-bit words: divided by 16), the same for the whole sequence.
class FrameSource {
 public:
  // Throws dropfit::InputError naming the path when it cannot be opened.
  explicit FrameSource(const std::string& path);
  ~FrameSource();
  FrameSource(FrameSource&&) noexcept;
  FrameSource& operator=(FrameSource&&) noexcept;

  // Frame count: exact for a sequence, the container's claim for a video
  // (-1 when it does not say).
  int size() const;
  // The frame number of the first frame: the first file's number for a
  // sequence, 0 for a video.
  int first_frame() const;
  // The next frame, false at the end. Throws dropfit::InputError naming the
  // file (or the video and frame) when a frame cannot be decoded or changes size.
  bool next(Image8& frame);
  int frames_read() const;
  const std::string& path() const;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

// Reads every frame of `frames` into `tracker` (progress shown when given).
// Returns the tracker's result, its rows numbered from 0 in reading order.
TrackingResult track_frames(FrameSource& frames, MarkerTracker& tracker, Progress* progress = nullptr);

// One camera's footage tracked with seeds whose frames are the footage's
// own numbers (a seed at frame 399 of a sequence exported from 399 is its
// first file). The result's rows are those numbers (shift_frames): row k is
// frame k. A seed before the first frame is an InputError naming its file
// and line.
TrackingResult track_footage(FrameSource& frames, const std::string& camera, const std::vector<std::string>& points,
                             std::vector<Seed> seeds, const TrackingOptions& options = {},
                             Progress* progress = nullptr);

}  // namespace dropfit::capture
