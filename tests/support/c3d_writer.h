#pragma once
// A small C3D writer for tests, from the format's public description (the
// C3D User Guide, as summarised in capture/c3d.h): a header block, the
// parameter section (groups and parameters, int8 / int16 / float / char),
// and the data section (per frame: each point's X Y Z and the residual word,
// then the analog samples), in the Intel, DEC (VAX floats) or MIPS processor
// formats, integer (scaled by the point scale factor) or floating point.
#include <Eigen/Core>

#include <bit>
#include <cstdint>
#include <string>
#include <vector>

#include "capture/c3d.h"

namespace dropfit::testsupport::c3d {

using capture::C3dProcessor;

struct Param {
  std::string name;
  int type;  // -1 char, 1 byte, 2 int16, 4 float
  std::vector<int> dims;
  std::vector<double> numbers;
  std::vector<std::string> strings;  // char: padded to dims[0]
};
struct Group {
  std::string name;
  std::vector<Param> params;
};

struct Spec {
  C3dProcessor processor = C3dProcessor::Intel;
  bool float_data = false;
  double point_scale = 0.1;  // magnitude; negated for float files
  double point_rate_hz = 100.0;
  int first_frame = 1;
  int n_frames = 5;
  int n_points = 0;
  int analog_per_frame = 10;
  int n_analog = 0;
  std::vector<Group> groups;
  // Stored values: points n_frames x 4 n_points (X Y Z word4), analog
  // (n_frames analog_per_frame) x n_analog.
  Eigen::MatrixXd points;
  Eigen::MatrixXd analog;
};

class Bytes {
 public:
  explicit Bytes(C3dProcessor p) : p_(p) {}
  std::string data;
  void u8(int v) { data += static_cast<char>(static_cast<std::uint8_t>(v)); }
  void u16(int v) {
    const auto u = static_cast<std::uint16_t>(v);
    if (p_ == C3dProcessor::Mips) {
      u8(u >> 8);
      u8(u & 0xFF);
    } else {
      u8(u & 0xFF);
      u8(u >> 8);
    }
  }
  void f32(double v) {
    const float f = static_cast<float>(v);
    std::uint32_t u = std::bit_cast<std::uint32_t>(f);
    if (p_ == C3dProcessor::Mips) {
      for (int s = 24; s >= 0; s -= 8) u8((u >> s) & 0xFF);
    } else if (p_ == C3dProcessor::Intel) {
      for (int s = 0; s <= 24; s += 8) u8((u >> s) & 0xFF);
    } else {
      // VAX F-float: 4 x the value as IEEE bits, 16-bit words swapped.
      if (f == 0.0f) {
        for (int k = 0; k < 4; ++k) u8(0);
        return;
      }
      u = std::bit_cast<std::uint32_t>(f * 4.0f);
      const std::uint32_t hi = u >> 16, lo = u & 0xFFFF;
      u8(hi & 0xFF);
      u8(hi >> 8);
      u8(lo & 0xFF);
      u8(lo >> 8);
    }
  }
  void pad_to_block() {
    while (data.size() % 512 != 0) data += '\0';
  }

 private:
  C3dProcessor p_;
};

inline std::string write_c3d(const Spec& s) {
  const C3dProcessor p = s.processor;
  // Parameter section first, to know its size.
  Bytes par(p);
  par.u8(1);
  par.u8(0x50);
  par.u8(0);  // block count, patched below
  par.u8(static_cast<int>(p));
  for (std::size_t g = 0; g < s.groups.size(); ++g) {
    const int id = static_cast<int>(g) + 1;
    const Group& gr = s.groups[g];
    par.u8(static_cast<int>(gr.name.size()));
    par.u8(-id);
    par.data += gr.name;
    par.u16(2 + 1);  // offset field + description length byte
    par.u8(0);
    for (const Param& pm : gr.params) {
      par.u8(static_cast<int>(pm.name.size()));
      par.u8(id);
      par.data += pm.name;
      Bytes body(p);
      body.u8(pm.type);
      body.u8(static_cast<int>(pm.dims.size()));
      for (int d : pm.dims) body.u8(d);
      if (pm.type == -1) {
        for (const std::string& str : pm.strings) {
          std::string padded = str;
          padded.resize(static_cast<std::size_t>(pm.dims[0]), ' ');
          body.data += padded;
        }
      } else {
        for (double v : pm.numbers) {
          if (pm.type == 1) body.u8(static_cast<int>(v));
          else if (pm.type == 2) body.u16(static_cast<int>(v));
          else body.f32(v);
        }
      }
      body.u8(0);  // description
      par.u16(static_cast<int>(2 + body.data.size()));
      par.data += body.data;
    }
  }
  par.u8(0);  // end
  par.u8(0);
  par.pad_to_block();
  const int param_blocks = static_cast<int>(par.data.size() / 512);
  par.data[2] = static_cast<char>(param_blocks);

  Bytes head(p);
  head.u8(2);
  head.u8(0x50);
  head.u16(s.n_points);
  head.u16(s.n_analog * s.analog_per_frame);
  head.u16(s.first_frame);
  head.u16(s.first_frame + s.n_frames - 1);
  head.u16(0);
  head.f32(s.float_data ? -s.point_scale : s.point_scale);
  head.u16(2 + param_blocks);
  head.u16(s.analog_per_frame);
  head.f32(s.point_rate_hz);
  head.pad_to_block();

  Bytes data(p);
  for (int f = 0; f < s.n_frames; ++f) {
    for (int k = 0; k < 4 * s.n_points; ++k) {
      if (s.float_data) data.f32(s.points(f, k));
      else data.u16(static_cast<int>(s.points(f, k)));
    }
    for (int a = 0; a < s.analog_per_frame; ++a)
      for (int c = 0; c < s.n_analog; ++c) {
        const double v = s.analog(f * s.analog_per_frame + a, c);
        if (s.float_data) data.f32(v);
        else data.u16(static_cast<int>(v));
      }
  }
  data.pad_to_block();
  return head.data + par.data + data.data;
}


inline Param num(const std::string& name, int type, std::vector<int> dims, std::vector<double> v) {
  return {name, type, std::move(dims), std::move(v), {}};
}
inline Param str(const std::string& name, int len, std::vector<std::string> v) {
  std::vector<int> dims{len, static_cast<int>(v.size())};
  return {name, -1, dims, {}, std::move(v)};
}

}  // namespace dropfit::testsupport::c3d
