/* contact_sheet.h: one synchronized set of a take as a PNG grid (libpng), so
 * a person sees at a glance that the views of a set belong together. */
#ifndef F4D_CONTACT_SHEET_H
#define F4D_CONTACT_SHEET_H

#include <stddef.h>
#include <stdint.h>

#include "f4d_status.h"

/* Writes set `index` of the take in `dir` (or, if index is UINT64_MAX, the
 * first complete set) to `png_path`: views side by side, 2 columns for 4
 * views, absent views grey. Returns 0 or <0 with err filled. */
int f4d_contact_sheet(const char *dir, uint64_t index, const char *png_path, struct f4d_err *err);

#endif
