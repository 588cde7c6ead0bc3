// Weight files: our own name -> tensor dictionary (save/load) and the import of the authors'
// release state dict. Both sets of names are documented in docs/weights.md.
#include <map>
#include <sstream>
#include <stdexcept>

#include "model/able_nerf.h"
#include "util/errors.h"
#include "util/fs.h"
#include "model/model_config.h"

namespace ablenerf {

namespace {

const std::string kLightningPrefix = "model.";
const std::string kUnusedReleasePrefix = "dir_query.";  // built but never used by the release

// Suffixes of one transformer block: release -> ours.
const std::vector<std::pair<std::string, std::string>>& block_suffixes() {
  static const std::vector<std::pair<std::string, std::string>> s = {{"attn.in_proj_weight", "attn.in_proj_weight"},
                                                                     {"attn.in_proj_bias", "attn.in_proj_bias"},
                                                                     {"attn.out_proj.weight", "attn.out_proj.weight"},
                                                                     {"attn.out_proj.bias", "attn.out_proj.bias"},
                                                                     {"ff_layer.0.weight", "ff_in.weight"},
                                                                     {"ff_layer.0.bias", "ff_in.bias"},
                                                                     {"ff_layer.3.weight", "ff_out.weight"},
                                                                     {"ff_layer.3.bias", "ff_out.bias"},
                                                                     {"norm1.weight", "norm1.weight"},
                                                                     {"norm1.bias", "norm1.bias"},
                                                                     {"norm2.weight", "norm2.weight"},
                                                                     {"norm2.bias", "norm2.bias"}};
  return s;
}

std::string shape_string(at::IntArrayRef sizes) {
  std::ostringstream ss;
  ss << sizes;
  return ss.str();
}

// Validates `dict` against `names` (external name -> our parameter name) completely, then
// copies. Errors name the external name.
void assign_parameters(AbleNerf& model, const c10::Dict<c10::IValue, c10::IValue>& dict,
                       const std::vector<std::pair<std::string, std::string>>& names, const std::string& origin,
                       bool release) {
  const auto params = model->named_parameters();
  const std::map<std::string, std::string> lookup(names.begin(), names.end());
  std::map<std::string, torch::Tensor> staged;  // our name -> value
  for (const auto& entry : dict) {
    if (!entry.key().isString()) throw InputError(origin, "", "dictionary keys must be strings");
    std::string name = entry.key().toStringRef();
    if (release && name.rfind(kLightningPrefix, 0) == 0) name = name.substr(kLightningPrefix.size());
    if (release && name.rfind(kUnusedReleasePrefix, 0) == 0) continue;
    const auto it = lookup.find(name);
    if (it == lookup.end()) throw InputError(origin, name, "unexpected parameter");
    if (!entry.value().isTensor()) throw InputError(origin, name, "not a tensor");
    const auto value = entry.value().toTensor();
    const auto& target = params[it->second];
    if (value.sizes() != target.sizes())
      throw InputError(origin, name,
                       "expected shape " + shape_string(target.sizes()) + " got " + shape_string(value.sizes()));
    if (!value.is_floating_point()) throw InputError(origin, name, "expected a floating-point tensor");
    if (!staged.emplace(it->second, value).second) throw InputError(origin, name, "given twice");
  }
  for (const auto& [external, ours] : names)
    if (!staged.count(ours)) throw InputError(origin, external, "missing");
  torch::NoGradGuard no_grad;
  for (const auto& [ours, value] : staged) {
    auto p = params[ours];
    p.copy_(value.to(p.device(), p.scalar_type()));
  }
}

}  // namespace

std::vector<std::pair<std::string, std::string>> release_name_map(const ModelConfig& cfg) {
  std::vector<std::pair<std::string, std::string>> m;
  auto linear = [&](const std::string& rel, const std::string& ours) {
    m.emplace_back(rel + ".weight", ours + ".weight");
    m.emplace_back(rel + ".bias", ours + ".bias");
  };
  auto block = [&](const std::string& rel, const std::string& ours) {
    for (const auto& [rs, os] : block_suffixes()) m.emplace_back(rel + "." + rs, ours + "." + os);
  };
  m.emplace_back("color_token", "ray_token");
  for (int i = 0; i < VolumeEmbeddingImpl::kLayers; ++i)  // Sequential(Linear, ReLU, ...): even indices
    linear("point_embedding." + std::to_string(2 * i), "volume_embedding.linear" + std::to_string(i));
  for (int i = 0; i < cfg.coarse_layers; ++i)
    block("coarse.layers." + std::to_string(i), "coarse.blocks." + std::to_string(i));
  for (int i = 0; i < cfg.fine_layers; ++i)
    block("fine.layers." + std::to_string(i), "fine.blocks." + std::to_string(i));
  linear("rgb_c_diff.0", "ray_head_coarse.linear");
  linear("rgb_f_diff.0", "ray_head_fine.linear");
  if (cfg.le_count > 0) {
    m.emplace_back("light_probes", "le");
    linear("view_token.0", "view_token");
    for (const auto& [rel, ours] : {std::pair<std::string, std::string>{"c", "coarse"}, {"f", "fine"}}) {
      block(rel + "_spec_colour.cross_attn", "le_" + ours + ".cross");
      for (int j = 0; j < cfg.le_layers; ++j)
        block(rel + "_spec_colour.self_attn." + std::to_string(j), "le_" + ours + ".self." + std::to_string(j));
      block(rel + "_spec_colour.decode", "le_" + ours + ".decode");
      linear(rel + "_spec_rgb.0", "le_head_" + ours + ".hidden");
      linear(rel + "_spec_rgb.2", "le_head_" + ours + ".out");
    }
  }
  return m;
}

const char* const kCameraRefineWeight = "camera_refine.correction";
const char* const kCameraRefineFocalWeight = "camera_refine.focal";

void save_weights(AbleNerf& model, const std::string& path) {
  c10::Dict<std::string, torch::Tensor> dict;
  for (const auto& p : model->named_parameters()) dict.insert(p.key(), p.value().detach().cpu().contiguous());
  const std::vector<char> bytes = torch::pickle_save(c10::IValue(dict));
  write_file_atomic(path, {bytes.data(), bytes.size()});
}

c10::Dict<c10::IValue, c10::IValue> read_weights_dict(const std::string& path) {
  const std::string file = read_file(path);
  const std::vector<char> bytes(file.begin(), file.end());
  c10::IValue v;
  try {
    v = torch::pickle_load(bytes);
  } catch (const c10::Error& e) {
    throw InputError(path, "", "not a torch.save / pickle_save file");
  }
  if (!v.isGenericDict()) throw InputError(path, "", "expected a name -> tensor dictionary");
  return v.toGenericDict();
}

void load_weights(AbleNerf& model, const std::string& path) {
  const auto dict = read_weights_dict(path);
  // Weights trained with per-photo colour, camera refinement or appearance codes carry them
  // (model/photo_colour.h, model/camera_refine.h, model/appearance_code.h): made here with their rows.
  const auto rows_of = [&](const char* key, int64_t dims, int64_t inner, const char* expected) -> int64_t {
    const auto it = dict.find(c10::IValue(std::string(key)));
    if (it == dict.end() || !it->value().isTensor()) return 0;
    const auto t = it->value().toTensor();
    if (t.dim() != dims || t.size(0) < 1 || t.size(-1) != inner) throw InputError(path, key, expected);
    return t.size(0);
  };
  if (!model->photo_colour()) {
    if (const int64_t n = rows_of(kPhotoColourAffineWeight, 3, 4, "expected (photos, 3, 4)"))
      model->enable_photo_colour(n, PhotoColourMap::Affine);
    else if (const int64_t g = rows_of(kPhotoColourGainWeight, 2, 3, "expected (photos, 3)"))
      model->enable_photo_colour(g, PhotoColourMap::Gain);
  }
  if (!model->camera_refine())
    if (const int64_t n = rows_of(kCameraRefineWeight, 2, 6, "expected (cameras, 6)"))
      model->enable_camera_refine(n, rows_of(kCameraRefineFocalWeight, 1, 1, "expected (1): one focal scale") > 0);
  if (!model->appearance_code()) {
    const int64_t width = model->config().width;
    const std::string expected = "expected (photos, " + std::to_string(width) + "): model.width codes";
    if (const int64_t n = rows_of(kAppearanceCodeWeight, 2, width, expected.c_str())) {
      try {
        model->enable_appearance_code(n);
      } catch (const std::invalid_argument& e) {  // the model's refusal (no LEs), named by the key
        throw InputError(path, kAppearanceCodeWeight, e.what());
      }
    }
  }
  std::vector<std::pair<std::string, std::string>> identity;
  for (const auto& p : model->named_parameters()) identity.emplace_back(p.key(), p.key());
  assign_parameters(model, dict, identity, path, /*release=*/false);
}

void import_release_weights(AbleNerf& model, const c10::Dict<c10::IValue, c10::IValue>& dict,
                            const std::string& origin) {
  if (model->config().embedding != Embedding::Ipe)
    throw InputError(origin, "model.embedding", "the release has no grid front end: import with \"ipe\"");
  assign_parameters(model, dict, release_name_map(model->config()), origin, /*release=*/true);
}

}  // namespace ablenerf
