#include "tofkit/link/decoder.hpp"

#include <stdexcept>
#include <string>

namespace tofkit::link {

namespace detail {
std::unique_ptr<Decoder> make_native_decoder(const DecoderOptions& options);
std::unique_ptr<Decoder> make_tfmini_decoder(const DecoderOptions& options);
std::unique_ptr<Decoder> make_lwnx_decoder(const DecoderOptions& options);
std::unique_ptr<Decoder> make_rplidar_decoder(const DecoderOptions& options);
}  // namespace detail

std::string_view format_name(Format format) {
  switch (format) {
    case Format::kNative:
      return "native";
    case Format::kTfmini:
      return "tfmini";
    case Format::kLwnx:
      return "lwnx";
    case Format::kRplidar:
      return "rplidar";
  }
  return "?";
}

Format format_from_name(std::string_view name) {
  for (const Format f : {Format::kNative, Format::kTfmini, Format::kLwnx, Format::kRplidar}) {
    if (format_name(f) == name) return f;
  }
  throw std::invalid_argument("unknown link format '" + std::string(name) +
                              "' (native, tfmini, lwnx, rplidar)");
}

std::string DecoderCounters::summary() const {
  using std::to_string;
  return to_string(frames) + " frames, " + to_string(other_packets) + " other packets, " +
         to_string(bytes_in) + " bytes in, " + to_string(bytes_skipped) + " skipped, " +
         to_string(checksum_failures) + " checksum failures, " + to_string(length_errors) +
         " length errors, " + to_string(resyncs) + " resyncs, " + to_string(sequence_gaps) +
         " frames missing by sequence number";
}

std::unique_ptr<Decoder> make_decoder(Format format, const DecoderOptions& options) {
  switch (format) {
    case Format::kNative:
      return detail::make_native_decoder(options);
    case Format::kTfmini:
      return detail::make_tfmini_decoder(options);
    case Format::kLwnx:
      return detail::make_lwnx_decoder(options);
    case Format::kRplidar:
      return detail::make_rplidar_decoder(options);
  }
  throw std::invalid_argument("make_decoder: unknown format");
}

}  // namespace tofkit::link
