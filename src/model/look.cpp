#include "model/look.h"

#include "util/errors.h"

namespace ablenerf {

int64_t look_photos(AbleNerfImpl& model) {
  if (model.photo_colour()) return model.photo_colour()->photos();
  if (model.appearance_code()) return model.appearance_code()->photos();
  return 0;
}

PhotoLook photo_look(AbleNerfImpl& model, int64_t look, const std::string& where, const std::string& field) {
  PhotoLook l;
  if (look < 0) return l;
  const int64_t photos = look_photos(model);
  if (photos == 0)
    throw InputError(where, field,
                     "the run learnt no per-photo colour or appearance (train.photo_colour, train.appearance_code)");
  if (look >= photos)
    throw InputError(where, field, "must be below " + std::to_string(photos) + " (the training photos)");
  l.photo = look;
  l.colour = model.photo_colour();
  if (AppearanceCodeImpl* codes = model.appearance_code()) l.appearance = codes->look(look);
  return l;
}

}  // namespace ablenerf
