# 3. Hide it: the simulated car, its accelerometer reading 6% low, driven at two speeds
stid-sim --fast --effect-file docs/examples/accel_scale_truth.py --speed 4 --duration 20 --seed 1 -o run_4ms.mcap
stid-sim --fast --effect-file docs/examples/accel_scale_truth.py --speed 6 --duration 20 --seed 2 -o run_6ms.mcap
# 4. See the gap: the catalogue has no effect for it
stid diagnose run_4ms.mcap run_6ms.mcap --vehicle docs/examples/rc8.toml
# 5. Add it: stid loads your effect from the file named in STID_EFFECTS
export STID_EFFECTS=docs/examples/accel_scale.py
stid diagnose run_4ms.mcap run_6ms.mcap --vehicle docs/examples/rc8.toml
# 6. See the error fall
stid fit run_4ms.mcap run_6ms.mcap --vehicle docs/examples/rc8.toml --model bicycle
stid fit run_4ms.mcap run_6ms.mcap --vehicle docs/examples/rc8.toml --model bicycle+accel_scale
