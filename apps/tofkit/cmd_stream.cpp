// tofkit stream: a device's byte stream (serial port, pty, capture file or
// stdin) decoded frame by frame, corrected live with a model, written as CSV
// rows as they arrive. Columns: sequence, time_s, (RPLIDAR: scan_angle_deg,
// scan_start), the raw CSV columns (truth columns empty), with --model the
// corrected columns, and link_status (LinkStatus bits). Ctrl-C ends cleanly.
// A file --out goes through the one writer (io::write_file_atomically): it
// appears, complete, when the stream ends (Ctrl-C included); a failing stream
// keeps an existing file, and an input (--in, --model) is never written over.
// `--out -` writes the rows to stdout as they arrive.

#include <fmt/format.h>

#include <atomic>
#include <chrono>
#include <cmath>
#include <csignal>
#include <cstdio>
#include <filesystem>
#include <iostream>
#include <memory>
#include <optional>
#include <ostream>
#include <string>
#include <vector>

#include "app.hpp"
#include "tofkit/io/atomic_file.hpp"
#include "tofkit/io/byte_source.hpp"
#include "tofkit/io/model_json.hpp"
#include "tofkit/io/raw_csv.hpp"
#include "tofkit/link/decoder.hpp"
#include "tofkit/ranging/pipeline.hpp"

namespace tofkit::app {
namespace {

struct StreamOptions {
  std::string format;
  std::string in;
  int baud = 0;
  std::string model;
  std::uint64_t count = 0;  // 0: until the stream ends
  std::string out;
  bool stats = false;
  std::uint32_t lwnx_distance_output = link::DecoderOptions{}.lwnx_distance_output;
  bool tfmini_no_temperature = false;
};

std::atomic<bool> g_stop{false};
extern "C" void on_stream_signal(int) {
  g_stop = true;
}

void append_number(fmt::memory_buffer& b, double v) {
  b.push_back(',');
  if (!std::isnan(v)) fmt::format_to(std::back_inserter(b), "{}", v);
}

class RowWriter {
 public:
  RowWriter(std::ostream& out, link::Format format, bool corrected)
      : out_(out), format_(format), corrected_(corrected) {
    fmt::memory_buffer b;
    fmt::format_to(std::back_inserter(b), "sequence,time_s");
    if (format_ == link::Format::kRplidar)
      fmt::format_to(std::back_inserter(b), ",scan_angle_deg,scan_start");
    for (const auto c : io::raw_csv_columns()) fmt::format_to(std::back_inserter(b), ",{}", c);
    if (corrected_) {
      for (const auto c : io::corrected_csv_columns())
        fmt::format_to(std::back_inserter(b), ",{}", c);
    }
    fmt::format_to(std::back_inserter(b), ",link_status\n");
    put(b);
  }

  void rows(const std::vector<link::Frame>& frames, const std::vector<double>& time_s,
            const std::vector<ranging::Range>& ranges) {
    fmt::memory_buffer b;
    for (std::size_t i = 0; i < frames.size(); ++i) {
      const link::Frame& f = frames[i];
      fmt::format_to(std::back_inserter(b), "{}", f.sequence);
      append_number(b, time_s[i]);
      if (format_ == link::Format::kRplidar) {
        append_number(b, f.scan_angle_deg);
        fmt::format_to(std::back_inserter(b), ",{}", f.scan_start ? 1 : 0);
      }
      b.append(
          std::string_view(",,,,"));  // truth: distance_true_m, reflectance, angle_deg, ambient_c
      const ranging::RawMeasurement& m = f.raw;
      for (const double v :
           {m.tof_ns, m.distance_raw_m, m.pulse_width_ns, m.amplitude, m.temperature_c}) {
        append_number(b, v);
      }
      fmt::format_to(std::back_inserter(b), ",{},{}", m.shots_valid, m.flags);
      if (corrected_) {
        append_number(b, ranges[i].distance_m);
        append_number(b, ranges[i].sigma_m);
        fmt::format_to(std::back_inserter(b), ",{}", ranges[i].correction_flags);
      }
      fmt::format_to(std::back_inserter(b), ",{}\n", f.status);
    }
    put(b);
  }

 private:
  void put(const fmt::memory_buffer& b) {
    out_.write(b.data(), static_cast<std::streamsize>(b.size()));
    out_.flush();  // rows as they arrive (stdout); a failed write ends the stream
    if (!out_) throw std::runtime_error("writing the output failed");
  }
  std::ostream& out_;
  link::Format format_;
  bool corrected_;
};

void run_stream(const StreamOptions& o) {
  const link::Format format = link::format_from_name(o.format);
  if (o.in.empty()) throw std::runtime_error("--in: empty path (a device, file, or - for stdin)");
  if (o.out.empty()) throw std::runtime_error("--out: empty path (a file, or - for stdout)");
  std::optional<ranging::Pipeline> pipeline;
  if (!o.model.empty()) pipeline = io::load_pipeline(o.model);  // an input of the command
  if (o.in != "-") io::note_input(o.in);
  io::ByteSource source(o.in, o.baud);  // restores a terminal's settings when it goes
  link::DecoderOptions options;
  options.lwnx_distance_output = o.lwnx_distance_output;
  options.tfmini_temperature = !o.tfmini_no_temperature;
  auto decoder = link::make_decoder(format, options);

  std::uint64_t rows = 0;
  bool ended = false;
  const auto stream_rows = [&](std::ostream& out) {
    RowWriter writer(out, format, pipeline.has_value());

    std::signal(SIGINT, on_stream_signal);
    std::signal(SIGTERM, on_stream_signal);
    std::signal(SIGPIPE, SIG_IGN);

    const auto start = std::chrono::steady_clock::now();
    std::vector<std::uint8_t> buffer(1 << 16);
    std::vector<link::Frame> frames;
    std::vector<double> time_s;
    std::vector<ranging::RawMeasurement> raw;
    std::vector<ranging::Range> ranges;
    const auto emit = [&] {
      if (o.count > 0 && rows + frames.size() > o.count) frames.resize(o.count - rows);
      if (frames.empty()) return;
      // Device time where the format carries it, else the host's arrival time.
      const double arrival_s =
          std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
      time_s.assign(frames.size(), arrival_s);
      raw.resize(frames.size());
      for (std::size_t i = 0; i < frames.size(); ++i) {
        if (!std::isnan(frames[i].device_time_s)) time_s[i] = frames[i].device_time_s;
        raw[i] = frames[i].raw;
      }
      ranges.resize(frames.size());
      if (pipeline) pipeline->apply(raw, ranges);
      writer.rows(frames, time_s, ranges);
      rows += frames.size();
      frames.clear();
    };
    while (!g_stop && !ended && (o.count == 0 || rows < o.count)) {
      std::size_t got = 0;
      const auto status = source.read(buffer, 100, got);
      if (status == io::ByteSource::Status::kEnd) ended = true;
      if (got > 0) decoder->feed({buffer.data(), got}, frames);
      emit();
    }
    if (ended) {
      decoder->finish(frames);
      emit();
    }
  };
  if (o.out == "-") {
    stream_rows(std::cout);
  } else {
    io::write_file_atomically(o.out, stream_rows);
  }
  const auto& c = decoder->counters();
  fmt::print(stderr, "tofkit stream: {} rows ({}){} -> {}\n", rows,
             ended ? "end of stream" : (g_stop ? "interrupted" : "--count reached"),
             pipeline ? ", corrected" : "", o.out == "-" ? "stdout" : o.out);
  if (o.stats) {
    fmt::print(stderr,
               "  frames {}\n  other_packets {}\n  bytes_in {}\n  bytes_skipped {}\n"
               "  checksum_failures {}\n  length_errors {}\n  resyncs {}\n  sequence_gaps {}\n",
               c.frames, c.other_packets, c.bytes_in, c.bytes_skipped, c.checksum_failures,
               c.length_errors, c.resyncs, c.sequence_gaps);
  } else {
    fmt::print(stderr, "  {}\n", c.summary());
  }
}

const bool registered = register_command("stream", [](CLI::App& sub, AppContext&) {
  sub.description(
      "decode a rangefinder's byte stream (serial port, pty, file or stdin) into CSV rows as they "
      "arrive, corrected live with --model");
  auto o = std::make_shared<StreamOptions>();
  sub.add_option("--format", o->format, "native, tfmini, lwnx or rplidar")
      ->check(CLI::IsMember({"native", "tfmini", "lwnx", "rplidar"}))
      ->required();
  sub.add_option("--in", o->in, "serial device, pty, capture file, or - for stdin")->required();
  sub.add_option("--baud", o->baud, "serial line speed (terminals only; default: leave as is)")
      ->check(InRange(1, 4'000'000));
  sub.add_option("--model", o->model, "model file (JSON, from tofkit fit) applied to every frame");
  sub.add_option("--count", o->count, "stop after this many frames (default: at end of stream)");
  sub.add_option("--out", o->out, "CSV to write, or - for stdout")->required();
  sub.add_flag("--stats", o->stats, "print every counter at the end");
  sub.add_option("--lwnx-distance-output", o->lwnx_distance_output,
                 "LWNX: the device's 'distance output' bits (command 27), which fix the fields "
                 "of its distance packets")
      ->capture_default_str();
  sub.add_flag("--tfmini-no-temperature", o->tfmini_no_temperature,
               "TFmini: the original TFmini (bytes 6-7 are not a temperature)");
  sub.callback([o] { run_stream(*o); });
});

}  // namespace
}  // namespace tofkit::app
