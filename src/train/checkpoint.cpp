#include "train/checkpoint.h"

#include <cstring>
#include <sstream>

#include "util/errors.h"
#include "util/fs.h"

namespace ablenerf {

namespace {

constexpr char kMagic[8] = {'A', 'B', 'L', 'E', 'C', 'K', 'P', 'T'};
constexpr uint32_t kFormatVersion = 1;
constexpr size_t kHeaderBytes = sizeof(kMagic) + sizeof(uint32_t) + 2 * sizeof(uint64_t);

// The model section of a config, as "key=value" lines: two checkpoints are compatible when these match.
std::string model_signature(const Config& c) {
  std::string s;
  for (const auto& [k, v] : c.items())
    if (k.rfind("model.", 0) == 0) s += k + "=" + v + "\n";
  return s;
}

// First differing line of two signatures, for the error message.
std::string first_difference(const std::string& a, const std::string& b) {
  std::istringstream sa(a), sb(b);
  std::string la, lb;
  while (true) {
    const bool ga = static_cast<bool>(std::getline(sa, la)), gb = static_cast<bool>(std::getline(sb, lb));
    if (!ga && !gb) return "";
    if (la != lb) return "checkpoint has " + (ga ? la : "<nothing>") + ", config has " + (gb ? lb : "<nothing>");
  }
}

template <typename T>
void put(std::string& out, T v) {
  out.append(reinterpret_cast<const char*>(&v), sizeof(T));
}

}  // namespace

uint64_t fnv1a64(const char* data, size_t size) {
  uint64_t h = 1469598103934665603ULL;
  for (size_t i = 0; i < size; ++i) {
    h ^= static_cast<unsigned char>(data[i]);
    h *= 1099511628211ULL;
  }
  return h;
}

void save_checkpoint(const std::string& path, const Config& config, AbleNerf& model, torch::optim::Adam& optim,
                     const TrainState& state) {
  torch::serialize::OutputArchive archive, model_archive, optim_archive;
  model->save(model_archive);
  optim.save(optim_archive);
  archive.write("model", model_archive);
  archive.write("optimizer", optim_archive);
  archive.write("step", torch::tensor(state.step, torch::kLong));
  archive.write("elapsed_seconds", torch::tensor(state.elapsed_seconds, torch::kDouble));
  archive.write("rng_state", state.rng_state.cpu());
  if (state.error_map.defined()) archive.write("error_map", state.error_map.cpu());
  // LibTorch's global CPU stream drives the stratified jitter (model.randomized) and the LE noise:
  // saved so that a resumed randomized run continues the same stream.
  archive.write("torch_rng_state", at::detail::getDefaultCPUGenerator().get_state());
  archive.write("model_signature", c10::IValue(model_signature(config)));
  archive.write("config", c10::IValue(config.to_toml()));
  std::ostringstream payload_stream;
  archive.save_to(payload_stream);
  const std::string payload = payload_stream.str();

  std::string file(kMagic, sizeof(kMagic));
  put(file, kFormatVersion);
  put(file, static_cast<uint64_t>(payload.size()));
  put(file, fnv1a64(payload.data(), payload.size()));
  file += payload;
  write_file_atomic(path, file);
}

TrainState load_checkpoint(const std::string& path, const Config& config, AbleNerf& model, torch::optim::Adam& optim) {
  const std::string bytes = read_file(path);
  if (bytes.size() < kHeaderBytes || std::memcmp(bytes.data(), kMagic, sizeof(kMagic)) != 0)
    throw InputError(path, "header", "not an ablenerf checkpoint (or truncated)");
  uint32_t version;
  uint64_t length, hash;
  size_t off = sizeof(kMagic);
  std::memcpy(&version, bytes.data() + off, sizeof(version));
  off += sizeof(version);
  std::memcpy(&length, bytes.data() + off, sizeof(length));
  off += sizeof(length);
  std::memcpy(&hash, bytes.data() + off, sizeof(hash));
  off += sizeof(hash);
  if (version != kFormatVersion)
    throw InputError(
        path, "version",
        "checkpoint format " + std::to_string(version) + ", this build reads " + std::to_string(kFormatVersion));
  if (bytes.size() - off != length)
    throw InputError(path, "length",
                     "truncated or padded: " + std::to_string(bytes.size() - off) + " payload bytes, header says " +
                         std::to_string(length));
  if (fnv1a64(bytes.data() + off, length) != hash) throw InputError(path, "checksum", "corrupted (checksum mismatch)");

  torch::serialize::InputArchive archive, model_archive, optim_archive;
  const auto params = model->parameters();
  const torch::Device device = params.empty() ? torch::Device(torch::kCPU) : params.front().device();
  archive.load_from(bytes.data() + off, length, device);
  c10::IValue sig;
  archive.read("model_signature", sig);
  const std::string diff = first_difference(sig.toStringRef(), model_signature(config));
  if (!diff.empty()) throw InputError(path, "config", "written for another model config: " + diff);
  archive.read("model", model_archive);
  model->load(model_archive);
  archive.read("optimizer", optim_archive);
  optim.load(optim_archive);
  TrainState st;
  torch::Tensor step, elapsed;  // fresh tensors: reading into a defined one reuses its dtype
  archive.read("step", step);
  st.step = step.item<int64_t>();
  archive.read("elapsed_seconds", elapsed);
  st.elapsed_seconds = elapsed.item<double>();
  archive.read("rng_state", st.rng_state);
  // Random-stream states are CPU byte tensors whatever device the archive was loaded onto.
  st.rng_state = st.rng_state.cpu();
  torch::Tensor map;
  if (archive.try_read("error_map", map)) st.error_map = map.cpu();
  torch::Tensor global_rng;
  if (archive.try_read("torch_rng_state", global_rng)) {
    at::Generator global = at::detail::getDefaultCPUGenerator();  // a handle to the global stream
    global.set_state(global_rng.cpu());
  }
  return st;
}

}  // namespace ablenerf
