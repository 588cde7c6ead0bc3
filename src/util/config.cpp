#include "util/config.h"

#define TOML_HEADER_ONLY 1
#define TOML_EXCEPTIONS 1
#include <toml++/toml.h>

#include <cmath>
#include <functional>
#include <map>
#include <sstream>
#include <variant>

#include "util/errors.h"
#include "util/fs.h"

namespace ablenerf {

namespace {

using FieldRef = std::variant<int*, int64_t*, double*, bool*, AttentionKernel*, Precision*, CpuSplit*, ViewEncoding*,
                              Background*, SsimVariant*, RaySampling*, SceneKind*, Embedding*, MaskSource*>;

// "must be \"a\" or \"b\"" from an enum's name table.
template <class E>
std::string allowed_names() {
  std::string s;
  const auto& t = enum_names<E>();
  for (size_t i = 0; i < t.size(); ++i)
    s += std::string(i == 0 ? "" : (i + 1 == t.size() ? " or " : ", ")) + "\"" + t[i].second + "\"";
  return "must be " + s;
}

// The schema: every key of the config, once.
template <typename C, typename F>
void visit_fields(C& c, F&& f) {
  f("model.width", &c.model.width);
  f("model.heads", &c.model.heads);
  f("model.ff_ratio", &c.model.ff_ratio);
  f("model.coarse_layers", &c.model.coarse_layers);
  f("model.fine_layers", &c.model.fine_layers);
  f("model.samples", &c.model.samples);
  f("model.embedding", &c.model.embedding);
  f("model.ipe_degrees", &c.model.ipe_degrees);
  f("model.grid_levels", &c.model.grid_levels);
  f("model.grid_features", &c.model.grid_features);
  f("model.grid_log2_table", &c.model.grid_log2_table);
  f("model.grid_base_resolution", &c.model.grid_base_resolution);
  f("model.grid_max_resolution", &c.model.grid_max_resolution);
  f("model.grid_ipe_degrees", &c.model.grid_ipe_degrees);
  f("model.grid_lr_scale", &c.model.grid_lr_scale);
  f("model.grid_bound", &c.model.grid_bound);
  f("model.proposal_samples", &c.model.proposal_samples);
  f("model.proposal_levels", &c.model.proposal_levels);
  f("model.proposal_max_resolution", &c.model.proposal_max_resolution);
  f("model.proposal_log2_table", &c.model.proposal_log2_table);
  f("model.le_count", &c.model.le_count);
  f("model.le_layers", &c.model.le_layers);
  f("model.mask", &c.model.mask);
  f("model.randomized", &c.model.randomized);
  f("model.view_encoding", &c.model.view_encoding);
  f("model.resample_padding", &c.model.resample_padding);
  f("data.downscale", &c.data.downscale);
  f("data.background", &c.data.background);
  f("data.near", &c.data.near);
  f("data.far", &c.data.far);
  f("data.scene", &c.data.scene);
  f("data.bounds_from_config", &c.data.bounds_from_config);
  f("data.masks", &c.data.masks);
  f("train.steps", &c.train.steps);
  f("train.rays_per_step", &c.train.rays_per_step);
  f("train.micro_batch", &c.train.micro_batch);
  f("train.lr_init", &c.train.lr_init);
  f("train.lr_final", &c.train.lr_final);
  f("train.lr_warmup_steps", &c.train.lr_warmup_steps);
  f("train.lr_warmup_mult", &c.train.lr_warmup_mult);
  f("train.lr_decay_steps", &c.train.lr_decay_steps);
  f("train.adam_beta1", &c.train.adam_beta1);
  f("train.adam_beta2", &c.train.adam_beta2);
  f("train.adam_eps", &c.train.adam_eps);
  f("train.coarse_weight", &c.train.coarse_weight);
  f("train.fine_weight", &c.train.fine_weight);
  f("train.distortion_weight", &c.train.distortion_weight);
  f("train.grid_decay", &c.train.grid_decay);
  f("train.proposal_weight", &c.train.proposal_weight);
  f("train.seed", &c.train.seed);
  f("train.log_every", &c.train.log_every);
  f("train.eval_every", &c.train.eval_every);
  f("train.eval_views", &c.train.eval_views);
  f("train.ckpt_every", &c.train.ckpt_every);
  f("train.max_bad_steps", &c.train.max_bad_steps);
  f("train.time_budget_s", &c.train.time_budget_s);
  f("train.ray_sampling", &c.train.ray_sampling);
  f("train.error_tile", &c.train.error_tile);
  f("train.error_uniform_share", &c.train.error_uniform_share);
  f("train.graph", &c.train.graph);
  f("eval.chunk", &c.eval.chunk);
  f("eval.ssim", &c.eval.ssim);
  f("compute.precision", &c.compute.precision);
  f("compute.attention", &c.compute.attention);
  f("compute.cpu_split", &c.compute.cpu_split);
}

std::map<std::string, FieldRef> field_map(Config& c) {
  std::map<std::string, FieldRef> m;
  visit_fields(c, [&](const char* k, auto* p) { m.emplace(k, FieldRef(p)); });
  return m;
}

std::string format_double(double v) {
  std::ostringstream ss;
  ss.precision(17);
  ss << v;
  std::string s = ss.str();
  if (s.find_first_of(".eEn") == std::string::npos) s += ".0";
  return s;
}

std::string value_string(const FieldRef& ref) {
  return std::visit(
      [](auto* p) -> std::string {
        using T = std::remove_pointer_t<decltype(p)>;
        if constexpr (std::is_same_v<T, bool>)
          return *p ? "true" : "false";
        else if constexpr (std::is_same_v<T, double>)
          return format_double(*p);
        else if constexpr (std::is_enum_v<T>)
          return std::string("\"") + name_of(*p) + "\"";
        else
          return std::to_string(*p);
      },
      ref);
}

// Sets a field from a TOML node; throws InputError on a type mismatch.
void set_from_node(const FieldRef& ref, const toml::node& node, const std::string& file, const std::string& key) {
  std::visit(
      [&](auto* p) {
        using T = std::remove_pointer_t<decltype(p)>;
        if constexpr (std::is_same_v<T, bool>) {
          if (!node.is_boolean()) throw InputError(file, key, "expected true or false");
          *p = node.as_boolean()->get();
        } else if constexpr (std::is_enum_v<T>) {
          const auto v = node.is_string() ? enum_from_name<T>(node.as_string()->get()) : std::nullopt;
          if (!v) throw InputError(file, key, allowed_names<T>());
          *p = *v;
        } else if constexpr (std::is_same_v<T, double>) {
          if (node.is_floating_point())
            *p = node.as_floating_point()->get();
          else if (node.is_integer())
            *p = static_cast<double>(node.as_integer()->get());
          else
            throw InputError(file, key, "expected a number");
          if (!std::isfinite(*p)) throw InputError(file, key, "must be finite");
        } else {
          if (!node.is_integer()) throw InputError(file, key, "expected an integer");
          const int64_t v = node.as_integer()->get();
          if constexpr (std::is_same_v<T, int>) {
            if (v < INT32_MIN || v > INT32_MAX) throw InputError(file, key, "out of range");
          }
          *p = static_cast<T>(v);
        }
      },
      ref);
}

void apply_table(Config& c, const toml::table& tbl, const std::string& file) {
  auto fields = field_map(c);
  for (const auto& [section, node] : tbl) {
    const std::string sec(section.str());
    const toml::table* st = node.as_table();
    if (!st) throw InputError(file, sec, "expected a [" + sec + "] table");
    for (const auto& [k, v] : *st) {
      const std::string key = sec + "." + std::string(k.str());
      auto it = fields.find(key);
      if (it == fields.end()) throw InputError(file, key, "unknown key");
      set_from_node(it->second, v, file, key);
    }
  }
}

}  // namespace

Config Config::parse(const std::string& text, const std::string& origin) {
  Config c;
  c.source = origin;
  toml::table tbl;
  try {
    tbl = toml::parse(std::string_view(text), std::string_view(origin));
  } catch (const toml::parse_error& e) {
    const auto& b = e.source().begin;
    throw InputError(origin, "line " + std::to_string(b.line), "invalid TOML: " + std::string(e.description()));
  }
  apply_table(c, tbl, origin);
  return c;
}

Config Config::load(const std::string& path) { return parse(read_file(path), path); }

void Config::set(const std::string& assignment) {
  const auto eq = assignment.find('=');
  if (eq == std::string::npos || eq == 0) throw InputError("--set", assignment, "expected section.key=value");
  const std::string key = assignment.substr(0, eq), value = assignment.substr(eq + 1);
  auto fields = field_map(*this);
  auto it = fields.find(key);
  if (it == fields.end()) throw InputError("--set", key, "unknown key");
  // Names may be given bare (--set data.background=black).
  const bool is_string =
      std::visit([](auto* p) { return std::is_enum_v<std::remove_pointer_t<decltype(p)>>; }, it->second);
  std::string doc = "v = " + ((is_string && (value.empty() || value[0] != '"')) ? "\"" + value + "\"" : value);
  toml::table tbl;
  try {
    tbl = toml::parse(std::string_view(doc), std::string_view("--set"));
  } catch (const toml::parse_error&) {
    throw InputError("--set", key, "cannot parse value '" + value + "'");
  }
  set_from_node(it->second, *tbl.get("v"), "--set", key);
}

void Config::validate() const {
  auto need = [&](bool ok, const char* key, const std::string& what) {
    if (!ok) throw InputError(source, key, what);
  };
  const auto& m = model;
  need(m.width > 0, "model.width", "must be positive");
  need(m.heads > 0 && m.width % m.heads == 0, "model.heads", "must divide model.width");
  need(m.ff_ratio > 0, "model.ff_ratio", "must be positive");
  need(m.coarse_layers >= 1, "model.coarse_layers", "must be at least 1 (the resampler reads its last layer)");
  need(m.fine_layers >= 1, "model.fine_layers", "must be at least 1");
  need(m.samples >= 2, "model.samples", "must be at least 2");
  need(m.ipe_degrees >= 1 && m.ipe_degrees <= 30, "model.ipe_degrees", "must be in 1..30");
  // The hash grid's limits (kernels/hash_grid.h).
  need(m.grid_levels >= 1 && m.grid_levels <= 32, "model.grid_levels", "must be in 1..32");
  need(m.grid_features >= 1 && m.grid_features <= 8, "model.grid_features", "must be in 1..8");
  need(m.grid_log2_table >= 1 && m.grid_log2_table <= 24, "model.grid_log2_table", "must be in 1..24");
  need(m.grid_base_resolution >= 1, "model.grid_base_resolution", "must be at least 1");
  need(m.grid_max_resolution >= m.grid_base_resolution && m.grid_max_resolution <= (1 << 20),
       "model.grid_max_resolution", "must be in model.grid_base_resolution..1048576");
  need(m.grid_ipe_degrees >= 0 && m.grid_ipe_degrees <= 30, "model.grid_ipe_degrees", "must be in 0..30");
  need(m.grid_lr_scale > 0, "model.grid_lr_scale", "must be positive");
  need(m.grid_bound > 0, "model.grid_bound", "must be positive");
  need(m.proposal_samples == 0 || (m.proposal_samples >= 2 && m.proposal_samples <= 1024), "model.proposal_samples",
       "must be 0 (off) or in 2..1024");
  need(m.proposal_levels >= 1 && m.proposal_levels <= 32, "model.proposal_levels", "must be in 1..32");
  need(m.proposal_log2_table >= 1 && m.proposal_log2_table <= 24, "model.proposal_log2_table", "must be in 1..24");
  need(m.proposal_max_resolution >= m.grid_base_resolution && m.proposal_max_resolution <= (1 << 20),
       "model.proposal_max_resolution", "must be in model.grid_base_resolution..1048576");
  need(m.le_count >= 0, "model.le_count", "must be >= 0");
  need(m.le_layers >= 0, "model.le_layers", "must be >= 0");
  need(m.resample_padding >= 0, "model.resample_padding", "must be >= 0");
  need(data.downscale >= 1, "data.downscale", "must be >= 1");
  need(data.near >= 0 && data.far > data.near, "data.far", "need 0 <= near < far");
  const auto& t = train;
  need(t.steps >= 0, "train.steps", "must be >= 0");
  need(t.rays_per_step >= 1, "train.rays_per_step", "must be >= 1");
  need(t.micro_batch >= 1, "train.micro_batch", "must be >= 1");
  need(t.lr_init > 0 && t.lr_final > 0, "train.lr_init", "learning rates must be positive");
  need(t.lr_warmup_steps >= 0, "train.lr_warmup_steps", "must be >= 0");
  need(t.lr_warmup_mult > 0 && t.lr_warmup_mult <= 1, "train.lr_warmup_mult", "must be in (0, 1]");
  need(t.lr_decay_steps >= 0, "train.lr_decay_steps", "must be >= 0");
  need(t.adam_beta1 >= 0 && t.adam_beta1 < 1, "train.adam_beta1", "must be in [0, 1)");
  need(t.adam_beta2 >= 0 && t.adam_beta2 < 1, "train.adam_beta2", "must be in [0, 1)");
  need(t.adam_eps > 0 && std::isfinite(t.adam_eps), "train.adam_eps", "must be > 0");
  need(t.coarse_weight >= 0 && t.fine_weight >= 0, "train.fine_weight", "loss weights must be >= 0");
  need(t.distortion_weight >= 0 && std::isfinite(t.distortion_weight), "train.distortion_weight", "must be >= 0");
  need(t.grid_decay >= 0 && std::isfinite(t.grid_decay), "train.grid_decay", "must be >= 0");
  need(t.proposal_weight >= 0 && std::isfinite(t.proposal_weight), "train.proposal_weight", "must be >= 0");
  need(t.log_every >= 1, "train.log_every", "must be >= 1");
  need(t.eval_every >= 0, "train.eval_every", "must be >= 0");
  need(t.eval_views >= 0, "train.eval_views", "must be >= 0");
  need(t.ckpt_every >= 0, "train.ckpt_every", "must be >= 0");
  need(t.max_bad_steps >= 1, "train.max_bad_steps", "must be >= 1");
  need(t.time_budget_s >= 0 && std::isfinite(t.time_budget_s), "train.time_budget_s", "must be >= 0 seconds");
  // The map keeps a masked pixel's place in its tile in 16 bits (train/error_map.h).
  need(t.error_tile >= 1 && t.error_tile <= 256, "train.error_tile", "must be in 1..256 pixels");
  need(t.error_uniform_share >= 0 && t.error_uniform_share <= 1, "train.error_uniform_share", "must be in [0, 1]");
  need(eval.chunk >= 1, "eval.chunk", "must be >= 1");
}

std::vector<std::pair<std::string, std::string>> Config::items() const {
  std::vector<std::pair<std::string, std::string>> out;
  Config copy = *this;
  visit_fields(copy, [&](const char* k, auto* p) { out.emplace_back(k, value_string(FieldRef(p))); });
  return out;
}

std::string Config::to_toml() const {
  std::string out, section;
  for (const auto& [key, value] : items()) {
    const auto dot = key.find('.');
    const std::string sec = key.substr(0, dot);
    if (sec != section) {
      out += (section.empty() ? "" : "\n") + ("[" + sec + "]\n");
      section = sec;
    }
    out += key.substr(dot + 1) + " = " + value + "\n";
  }
  return out;
}

}  // namespace ablenerf
