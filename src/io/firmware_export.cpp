#include "tofkit/io/firmware_export.hpp"

#include <cctype>
#include <cstdint>
#include <fstream>
#include <limits>
#include <sstream>
#include <stdexcept>
#include <string>
#include <vector>

#include "tofkit/io/atomic_file.hpp"
#include "tofkit/io/json_fields.hpp"

namespace tofkit::io {
namespace {

using json_fields::fail;
using json_fields::field;
using nlohmann::json;

constexpr const char* kKind = "tofkit.fixed_point_chain";
constexpr int kVersion = 1;

std::int64_t integer(const json& j, const std::string& where, std::int64_t lo, std::int64_t hi) {
  if (!j.is_number_integer()) fail(where, "expected an integer");
  if (j.is_number_unsigned() && j.get<std::uint64_t>() > static_cast<std::uint64_t>(hi)) {
    fail(where, "integer out of range");
  }
  const auto v = j.get<std::int64_t>();
  if (v < lo || v > hi) fail(where, "integer " + std::to_string(v) + " out of range");
  return v;
}

std::int32_t int32(const json& j, const char* key, const std::string& where) {
  return static_cast<std::int32_t>(integer(field(j, key, where), where + "." + key,
                                           std::numeric_limits<std::int32_t>::min(),
                                           std::numeric_limits<std::int32_t>::max()));
}

std::vector<std::int32_t> int32s(const json& j, const char* key, const std::string& where) {
  const json& v = field(j, key, where);
  const std::string here = where + "." + key;
  if (!v.is_array()) fail(here, "expected an array of integers");
  std::vector<std::int32_t> out;
  for (std::size_t k = 0; k < v.size(); ++k) {
    out.push_back(static_cast<std::int32_t>(integer(v[k], here + "[" + std::to_string(k) + "]",
                                                    std::numeric_limits<std::int32_t>::min(),
                                                    std::numeric_limits<std::int32_t>::max())));
  }
  return out;
}

double number(const json& j, const char* key, const std::string& where) {
  const json& v = field(j, key, where);
  if (!v.is_number()) fail(where + "." + key, "expected a number");
  return v.get<double>();
}

json hinge_to_json(const ranging::FixedPointHinge& h) {
  return {{"enabled", h.enabled},           {"slope0_q", h.slope0_q},
          {"knots_q", h.knots_q},           {"slopes_q", h.slopes_q},
          {"domain_min_q", h.domain_min_q}, {"domain_max_q", h.domain_max_q}};
}

ranging::FixedPointHinge hinge_from_json(const json& j, const std::string& where) {
  ranging::FixedPointHinge h;
  const json& enabled = field(j, "enabled", where);
  if (!enabled.is_boolean()) fail(where + ".enabled", "expected true or false");
  h.enabled = enabled.get<bool>();
  h.slope0_q = int32(j, "slope0_q", where);
  h.knots_q = int32s(j, "knots_q", where);
  h.slopes_q = int32s(j, "slopes_q", where);
  h.domain_min_q = int32(j, "domain_min_q", where);
  h.domain_max_q = int32(j, "domain_max_q", where);
  return h;
}

/// An int32 array initialiser padded to one element (C has no empty arrays).
std::string c_array(const std::vector<std::int32_t>& v) {
  std::string s = "{";
  if (v.empty()) s += "0";
  for (std::size_t k = 0; k < v.size(); ++k) s += (k ? ", " : "") + std::to_string(v[k]);
  return s + "}";
}

std::string c_int32(std::int32_t v) {
  // INT32_MIN cannot be written as a literal.
  return v == std::numeric_limits<std::int32_t>::min() ? "INT32_MIN" : std::to_string(v);
}

void hinge_to_c(std::ostringstream& out, const std::string& p, const char* name,
                const ranging::FixedPointHinge& h, const char* input) {
  const std::string n = p + "_" + name;
  const std::size_t count = h.enabled ? h.knots_q.size() : 0;
  out << "/* " << name << " hinge, x = " << input << " code; "
      << (h.enabled ? "enabled" : "disabled (all zero)") << " */\n";
  out << "#define " <<
      [&] {
        std::string upper = n;
        for (char& c : upper) c = static_cast<char>(std::toupper(static_cast<unsigned char>(c)));
        return upper;
      }()
      << "_KNOTS " << count << "\n";
  out << "static const int32_t " << n << "_slope0_q = " << (h.enabled ? h.slope0_q : 0) << ";\n";
  out << "static const int32_t " << n
      << "_knots_q[] = " << c_array(h.enabled ? h.knots_q : std::vector<std::int32_t>{}) << ";\n";
  out << "static const int32_t " << n
      << "_slopes_q[] = " << c_array(h.enabled ? h.slopes_q : std::vector<std::int32_t>{}) << ";\n";
  out << "static const int32_t " << n << "_domain_q[2] = {"
      << c_int32(h.enabled ? h.domain_min_q : std::numeric_limits<std::int32_t>::min()) << ", "
      << c_int32(h.enabled ? h.domain_max_q : std::numeric_limits<std::int32_t>::max()) << "};\n\n";
}

void check_prefix(std::string_view prefix) {
  bool ok =
      !prefix.empty() && (std::isalpha(static_cast<unsigned char>(prefix[0])) || prefix[0] == '_');
  for (char c : prefix) ok = ok && (std::isalnum(static_cast<unsigned char>(c)) || c == '_');
  if (!ok) {
    throw std::invalid_argument("firmware header prefix \"" + std::string(prefix) +
                                "\" is not a C identifier");
  }
}

}  // namespace

json fixed_point_to_json(const ranging::FixedPointChain& chain) {
  const ranging::FixedPointCoefficients& c = chain.coefficients();
  return {{"kind", kKind},
          {"version", kVersion},
          {"format",
           {{"tdc_lsb_ps", c.format.tdc_lsb_ps},
            {"pulse_width_lsb_ps", c.format.pulse_width_lsb_ps},
            {"temperature_lsb_c", c.format.temperature_lsb_c},
            {"fraction_bits", c.format.fraction_bits},
            {"knot_fraction_bits", c.format.knot_fraction_bits}}},
          {"output_unit", "um"},
          {"constant_q", c.constant_q},
          {"tof_scale_q", c.tof_scale_q},
          {"grayvalue", hinge_to_json(c.grayvalue)},
          {"temperature", hinge_to_json(c.temperature)}};
}

ranging::FixedPointChain fixed_point_from_json(const json& j, const std::string& context) {
  if (!j.is_object()) fail(context, "expected a JSON object");
  const json& kind = field(j, "kind", context);
  if (!kind.is_string() || kind.get<std::string>() != kKind) {
    fail(context + ".kind", "expected \"" + std::string(kKind) + "\"");
  }
  if (integer(field(j, "version", context), context + ".version", 0, 1000) != kVersion) {
    fail(context + ".version",
         "unsupported version (this tofkit reads " + std::to_string(kVersion) + ")");
  }
  ranging::FixedPointCoefficients c;
  const std::string fw = context + ".format";
  const json& f = field(j, "format", context);
  c.format.tdc_lsb_ps = number(f, "tdc_lsb_ps", fw);
  c.format.pulse_width_lsb_ps = number(f, "pulse_width_lsb_ps", fw);
  c.format.temperature_lsb_c = number(f, "temperature_lsb_c", fw);
  c.format.fraction_bits = int32(f, "fraction_bits", fw);
  c.format.knot_fraction_bits = int32(f, "knot_fraction_bits", fw);
  c.constant_q =
      integer(field(j, "constant_q", context), context + ".constant_q",
              std::numeric_limits<std::int64_t>::min(), std::numeric_limits<std::int64_t>::max());
  c.tof_scale_q = int32(j, "tof_scale_q", context);
  c.grayvalue = hinge_from_json(field(j, "grayvalue", context), context + ".grayvalue");
  c.temperature = hinge_from_json(field(j, "temperature", context), context + ".temperature");
  try {
    return ranging::FixedPointChain(std::move(c));
  } catch (const std::invalid_argument& e) {
    fail(context, e.what());
  }
}

std::string fixed_point_c_header(const ranging::FixedPointChain& chain, std::string_view prefix) {
  check_prefix(prefix);
  const ranging::FixedPointCoefficients& c = chain.coefficients();
  const std::string p(prefix);
  std::string guard = p + "_FIXED_POINT_CHAIN_H";
  for (char& ch : guard) ch = static_cast<char>(std::toupper(static_cast<unsigned char>(ch)));
  std::string upper = p;
  for (char& ch : upper) ch = static_cast<char>(std::toupper(static_cast<unsigned char>(ch)));
  std::ostringstream out;
  out.precision(17);
  out << "/* Generated by tofkit (io/firmware_export): fixed-point range correction.\n"
      << " * Do not edit; regenerate from the model.\n"
      << " *\n"
      << " * Inputs (integer codes): tof_code in TDC LSBs of " << c.format.tdc_lsb_ps << " ps,\n"
      << " *   pulse_width_code in LSBs of " << c.format.pulse_width_lsb_ps << " ps,\n"
      << " *   temperature_code in LSBs of " << c.format.temperature_lsb_c << " C.\n"
      << " * Output: distance in micrometres.\n"
      << " *   acc  = constant_q + tof_code * tof_scale_q                 [um * 2^-F]\n"
      << " *   x_q  = code * 2^K\n"
      << " *   acc += (slope0_q * x_q + sum_k slopes_q[k] * max(0, x_q - knots_q[k])) >> K\n"
      << " *   distance_um = (acc + 2^(F-1)) >> F\n"
      << " * F = " << c.format.fraction_bits << ", K = " << c.format.knot_fraction_bits
      << "; int64 intermediates; valid for |pulse width, temperature codes| < 2^16,\n"
      << " * 0 <= tof_code < 2^24. Right shifts of negative values are assumed arithmetic\n"
      << " * (true of GCC, Clang, MSVC and of an FPGA's signed shifter).\n"
      << " */\n"
      << "#ifndef " << guard << "\n#define " << guard << "\n\n#include <stdint.h>\n\n"
      << "#define " << upper << "_FRACTION_BITS " << c.format.fraction_bits << "\n"
      << "#define " << upper << "_KNOT_FRACTION_BITS " << c.format.knot_fraction_bits << "\n\n"
      << "static const int64_t " << p << "_constant_q = INT64_C(" << c.constant_q << ");\n"
      << "static const int32_t " << p << "_tof_scale_q = " << c.tof_scale_q << ";\n\n";
  hinge_to_c(out, p, "grayvalue", c.grayvalue, "pulse-width");
  hinge_to_c(out, p, "temperature", c.temperature, "temperature");
  out << "static inline int64_t " << p
      << "_hinge(int32_t code, int32_t slope0_q, const int32_t* knots_q, const int32_t* slopes_q,\n"
      << "                              int count, const int32_t* domain_q, uint32_t* "
         "out_of_domain) {\n"
      << "  const int64_t x_q = (int64_t)code * ((int64_t)1 << " << upper
      << "_KNOT_FRACTION_BITS);\n"
      << "  int64_t sum = (int64_t)slope0_q * x_q;\n"
      << "  for (int k = 0; k < count; ++k) {\n"
      << "    const int64_t over = x_q - knots_q[k];\n"
      << "    sum += (int64_t)slopes_q[k] * (over > 0 ? over : 0);\n"
      << "  }\n"
      << "  if (x_q < domain_q[0] || x_q > domain_q[1]) *out_of_domain = 1u;\n"
      << "  return sum >> " << upper << "_KNOT_FRACTION_BITS;\n"
      << "}\n\n"
      << "/* Corrected distance in micrometres; *out_of_domain = 1 if an input lies outside\n"
      << " * the calibrated range (the correction is still applied). */\n"
      << "static inline int32_t " << p
      << "_distance_um(int32_t tof_code, int32_t pulse_width_code, int32_t temperature_code,\n"
      << "                                 uint32_t* out_of_domain) {\n"
      << "  int64_t acc = " << p << "_constant_q + (int64_t)tof_code * " << p << "_tof_scale_q;\n"
      << "  *out_of_domain = 0u;\n"
      << "  acc += " << p << "_hinge(pulse_width_code, " << p << "_grayvalue_slope0_q, " << p
      << "_grayvalue_knots_q,\n"
      << "                  " << p << "_grayvalue_slopes_q, " << upper << "_GRAYVALUE_KNOTS, " << p
      << "_grayvalue_domain_q, out_of_domain);\n"
      << "  acc += " << p << "_hinge(temperature_code, " << p << "_temperature_slope0_q, " << p
      << "_temperature_knots_q,\n"
      << "                  " << p << "_temperature_slopes_q, " << upper << "_TEMPERATURE_KNOTS, "
      << p << "_temperature_domain_q, out_of_domain);\n"
      << "  return (int32_t)((acc + ((int64_t)1 << (" << upper << "_FRACTION_BITS - 1))) >> "
      << upper << "_FRACTION_BITS);\n"
      << "}\n\n"
      << "#endif /* " << guard << " */\n";
  return out.str();
}

void save_fixed_point_json(const std::filesystem::path& path,
                           const ranging::FixedPointChain& chain) {
  write_file_atomically(path, fixed_point_to_json(chain).dump(2) + "\n");
}

void save_fixed_point_header(const std::filesystem::path& path,
                             const ranging::FixedPointChain& chain, std::string_view prefix) {
  write_file_atomically(path, fixed_point_c_header(chain, prefix));
}

ranging::FixedPointChain load_fixed_point_json(const std::filesystem::path& path) {
  const json j = json_fields::parse_file(path, "firmware file");
  return fixed_point_from_json(j, path.string());
}

}  // namespace tofkit::io
