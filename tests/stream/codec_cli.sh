#!/usr/bin/env bash
# codec_cli.sh F4D_CODEC F4D_SCENE DIR: three scene keys -> stream -> PLY,
# PLY -> SPZ -> PLY, info on each kind, and errors that name the bad file.
set -euo pipefail
codec=$1 scenebin=$2 dir=$3
rm -rf "$dir" && mkdir -p "$dir"
"$scenebin" --preset wave --frames 3 --views 1 --size 64x64 -o "$dir/scene" >/dev/null
plys=("$dir"/scene/t*/gaussians.ply)
[ ${#plys[@]} -ge 3 ] || { echo "expected 3 PLY keys from f4d-scene, got ${#plys[@]}"; ls -R "$dir"; exit 1; }
"$codec" encode "${plys[@]:0:3}" -o "$dir/s.f4ds" --quality high --key-rate 10
"$codec" info "$dir/s.f4ds" | tee "$dir/info.txt"
grep -q "intra" "$dir/info.txt" && grep -q "predicted" "$dir/info.txt"
"$codec" decode "$dir/s.f4ds" -o "$dir/k1.ply" --frame 1
"$codec" decode "$dir/s.f4ds" -o "$dir/all_%02d.ply"
[ -s "$dir/all_02.ply" ]
"$codec" encode "${plys[0]}" -o "$dir/k0.spz"
"$codec" decode "$dir/k0.spz" -o "$dir/k0_back.ply"
"$codec" info "$dir/k0.spz" "$dir/k0_back.ply" | tee "$dir/info2.txt"
grep -q "SPZ" "$dir/info2.txt" && grep -q "PLY" "$dir/info2.txt"
# SPZ v4 (default: plain NGSP header) and v3 (gzip) both written and read back
[ "$(head -c 4 "$dir/k0.spz")" = "NGSP" ] || { echo "default SPZ is not v4"; exit 1; }
"$codec" encode "${plys[0]}" -o "$dir/k0v3.spz" --spz-version 3
[ "$(od -An -tx1 -N2 "$dir/k0v3.spz" | tr -d ' ')" = "1f8b" ] || { echo "--spz-version 3 is not gzip"; exit 1; }
"$codec" decode "$dir/k0v3.spz" -o "$dir/k0v3_back.ply"
cmp "$dir/k0_back.ply" "$dir/k0v3_back.ply"
# motions re-derived over the key interval (three keys of the same Gaussians)
"$codec" encode "${plys[@]:0:3}" -o "$dir/m.f4ds" --quality compact --motion-from-keys | tee "$dir/m.txt"
grep -q "predicted key" "$dir/m.txt"
"$codec" decode "$dir/m.f4ds" -o "$dir/m2.ply" --frame 2
# stream order and efforts: same keys, decodable; max no larger than default
"$codec" encode "${plys[@]:0:3}" -o "$dir/so.f4ds" --quality compact --motion-from-keys --stream-order --effort max >/dev/null
"$codec" encode "${plys[@]:0:3}" -o "$dir/sf.f4ds" --quality compact --motion-from-keys --effort fast >/dev/null
"$codec" decode "$dir/so.f4ds" -o "$dir/so_%02d.ply"
"$codec" decode "$dir/sf.f4ds" -o "$dir/sf2.ply" --frame 2
[ -s "$dir/so_02.ply" ] && [ -s "$dir/sf2.ply" ]
"$codec" encode "${plys[@]:0:3}" -o "$dir/sd.f4ds" --quality compact --motion-from-keys --stream-order >/dev/null
[ "$(stat -c %s "$dir/so.f4ds")" -le "$(stat -c %s "$dir/sd.f4ds")" ] || { echo "--effort max is larger than default"; exit 1; }
if "$codec" encode "${plys[0]}" -o "$dir/x.f4ds" --effort turbo 2> "$dir/err4.txt"; then exit 1; fi
grep -q "turbo" "$dir/err4.txt"
# errors name the file and the field
head -c 100 "$dir/s.f4ds" > "$dir/cut.f4ds"
if "$codec" decode "$dir/cut.f4ds" -o "$dir/x.ply" 2> "$dir/err.txt"; then echo "truncated stream decoded"; exit 1; fi
grep -q "cut.f4ds" "$dir/err.txt"
printf 'nonsense' > "$dir/bad.spz"
if "$codec" info "$dir/bad.spz" 2> "$dir/err2.txt"; then echo "bad file accepted"; exit 1; fi
grep -q "bad.spz" "$dir/err2.txt"
if "$codec" encode "${plys[0]}" -o "$dir/x.ply" --quality ultra 2> "$dir/err3.txt"; then exit 1; fi
grep -q "ultra" "$dir/err3.txt"
echo "codec_cli: ok"
