# Board profiles: pin map and ADC set-up. The sampler only sees `read` functions
# that return raw counts in the unit HELLO declares.
#
# Pico (RP2040): ADC on GP26-28 only (GP29 measures VSYS on the Pico board), so
# three analog channels: ax, ay and the yaw gyro; az is not sampled (planar
# dynamics need no az; mounting tilt is calibrated from ax, ay). ADC(Pin(n)), not
# ADC(n): by channel number the pad pull-down stays on. read_u16 scales 12 bits to
# 16; we send the native 12-bit count.
#
# ESP32 DevKit: ADC1 (GPIO32-39; ADC2 is unusable with WiFi). 11 dB attenuation
# converts ~0.15-2.45 V linearly only, and the reference is not the sensor supply,
# so we send read_uv() in millivolts and HELLO states the clip voltage. An ADXL335
# on 3.3 V swings to 2.64 V at +3 g: beyond +2.4 g (x, y) the reading clips.
#
# Hall wheel sensors: `wheel_pins` (one, the default) or `wheel_pins4` (all four
# wheels, App(wheels=4)), position -> pin; positions fl, fr, rl, rr. Records carry
# them in that order. `wheel_ppr`: magnets (pulses) per wheel revolution.
#
# Analog bandwidth, declared in HELLO: the ADXL335's output filter is its internal
# 32 kOhm with the board's output capacitor, f = 5 uF / C (`accel_cap_nf` = 100 nF =
# 0.1 uF -> 50 Hz); the LISY300AL filters internally at 88 Hz.
#
# Link: the Pico streams over USB-CDC (~7-9 Mbit/s). The ESP32 DevKit's console is
# UART 0 behind a USB bridge at 115200 baud, which carries only ~390 Hz of samples:
# the firmware sets it to `baud` (921600; CP210x/CH340 bridges take it). The REPL
# shares that UART, so a board running the app talks at 921600 until it resets.
# `hall_debounce_us`: hall edges closer than this to the previous one are contact
# bounce or noise (a wheel at 30 m/s with one magnet gives one edge per ~10 ms).
# `safe_pin`: held low at reset, the app does not start (main.py): the escape that
# needs no tools.
import machine
from machine import ADC, Pin

PROFILES = {
    "pico": {
        "adc": {"bits": 12, "vref": 3.3, "unit": "count"},
        "adc_clip_v": None,
        "pins": {"ax": 26, "ay": 27, "az": None, "yaw": 28, "vbat": None},
        "steer_pin": 2,
        "wheel_pins": {"rl": 3},
        "wheel_pins4": {"fl": 4, "fr": 5, "rl": 3, "rr": 6},
        "wheel_ppr": 1,
        "accel_cap_nf": 100,
        "timer_id": -1,
        "hard_timer": True,
        "link": {"kind": "usb", "baud": None},
        "hall_debounce_us": 200,
        "safe_pin": 22,
        "adc_scan": True,  # RP2040: ADC round robin into a DMA ring (adc_scan.py)
        "servo_pio": True,  # RP2040: servo pulses timed by a PIO state machine (servo_pio.py)
    },
    "esp32": {
        "adc": {"bits": 12, "vref": 3.3, "unit": "mV"},
        "adc_clip_v": 2.45,
        "pins": {"ax": 32, "ay": 33, "az": 34, "yaw": 35, "vbat": 36},
        "steer_pin": 25,
        "wheel_pins": {"rl": 26},
        "wheel_pins4": {"fl": 27, "fr": 14, "rl": 26, "rr": 13},
        "wheel_ppr": 1,
        "accel_cap_nf": 100,
        "timer_id": 0,
        "hard_timer": False,
        "link": {"kind": "uart", "baud": 921600, "uart": 0},
        "hall_debounce_us": 200,
        "safe_pin": 0,  # the DevKit's BOOT button, read after reset
        # no hardware scan: the ESP32's ADC DMA (I2S/"continuous" mode) is not exposed by
        # MicroPython
        "adc_scan": False,
        "servo_pio": False,
        # servo pulses timed by the pulse counter (servo_pcnt.py) against a 1 MHz clock the
        # PWM puts on this pin (leave it unconnected); MicroPython's esp32.RMT is transmit-only
        "servo_clock_pin": 18,
    },
}

PARTS = {
    "ax": ("ADXL335", "ratiometric"),
    "ay": ("ADXL335", "ratiometric"),
    "az": ("ADXL335", "ratiometric"),
    "yaw": ("LISY300AL", "absolute"),
    "vbat": ("divider", "absolute"),
}
CHANNELS = ("ax", "ay", "az", "yaw", "vbat")
WHEELS = ("fl", "fr", "rl", "rr")  # record order of the hall sensors
GYRO_BANDWIDTH_HZ = 88  # LISY300AL internal low-pass


def _missing():
    return 0xFFFF


class _Rp2Channel:
    def __init__(self, pin_no):
        self._read = ADC(Pin(pin_no)).read_u16

    def read(self):
        return self._read() >> 4


class _Esp32Channel:
    def __init__(self, pin_no):
        adc = ADC(Pin(pin_no), atten=ADC.ATTN_11DB)
        self._read = adc.read_uv

    def read(self):
        return (self._read() + 500) // 1000  # to the nearest mV (flooring read 0.5 mV low)


def open_channels(name):
    """Return (profile, readers) with one zero-argument read function per channel."""
    profile = PROFILES[name]
    make = _Rp2Channel if profile["adc"]["unit"] == "count" else _Esp32Channel
    readers = []
    for ch in CHANNELS:
        pin = profile["pins"][ch]
        readers.append(_missing if pin is None else make(pin).read)
    return profile, readers


def bandwidth_hz(profile, ch):
    """First-order output filter of a channel's sensor [Hz], or None (unknown/none)."""
    part = PARTS[ch][0]
    if part == "ADXL335":
        nf = profile["accel_cap_nf"]  # f = 5 uF / C_out (32 kOhm internal)
        return (5000 + nf // 2) // nf
    if part == "LISY300AL":
        return GYRO_BANDWIDTH_HZ
    return None


def channel_map(profile):
    out = {}
    for ch in CHANNELS:
        pin = profile["pins"][ch]
        out[ch] = None if pin is None else {"pin": pin, "part": PARTS[ch][0], "out": PARTS[ch][1],
                                            "bandwidth_hz": bandwidth_hz(profile, ch)}
    return out


def wheel_list(profile, wheel_pins=None):
    """The hall sensors in record order: [(position, pin), ...], one or four.

    wheel_pins: None (the profile's one sensor), 4 (the profile's four), or a dict
    position -> pin."""
    if wheel_pins is None:
        wheel_pins = profile["wheel_pins"]
    elif wheel_pins == 4:
        wheel_pins = profile["wheel_pins4"]
    for k in wheel_pins:
        if k not in WHEELS:
            raise ValueError("wheel position must be one of fl, fr, rl, rr, not " + str(k))
    out = [(k, wheel_pins[k]) for k in WHEELS if k in wheel_pins]
    if len(out) not in (1, 4):
        raise ValueError("one or four hall sensors are supported, not %d" % len(out))
    return out


def open_link(profile):
    """Set the board's output link up; return HELLO's `link` {kind, baud} (no bytes_per_sample)."""
    link = profile["link"]
    if link["kind"] == "uart":
        # the console UART: stdout goes through it, so only its baud rate changes
        machine.UART(link["uart"], baudrate=link["baud"])
    return {"kind": link["kind"], "baud": link["baud"]}


RESET_CAUSES = (("PWRON_RESET", "power_on"), ("HARD_RESET", "hard"), ("WDT_RESET", "watchdog"),
                ("DEEPSLEEP_RESET", "deepsleep"), ("SOFT_RESET", "soft"))


# rp2 reads WDT_RESET after machine.reset() as well (an escape, mpremote, `stid flash`):
# both go through the watchdog (ports/rp2/modmachine.c: watchdog_reboot; reset_cause is
# watchdog_caused_reboot, any REASON bit on the RP2040). The pico-sdk tells them apart in
# watchdog scratch register 4, which a reset keeps: watchdog_enable (machine.WDT) writes
# WATCHDOG_NON_REBOOT_MAGIC there, watchdog_reboot(0, ...) writes 0
# (src/rp2_common/hardware_watchdog/watchdog.c, watchdog_enable_caused_reboot).
_WDT_SCRATCH4 = {"RP2040": 0x4005801C, "RP2350": 0x400D801C}  # WATCHDOG_BASE + 0x1C
_WDT_NON_REBOOT_MAGIC = 0x6AB73121


def _rp2_reset_was_asked_for():
    import sys
    chip = "RP2350" if "RP2350" in getattr(sys.implementation, "_machine", "") else "RP2040"
    try:
        return machine.mem32[_WDT_SCRATCH4[chip]] != _WDT_NON_REBOOT_MAGIC
    except (AttributeError, OSError):
        return False


def reset_cause(board=None):
    """Why the chip last reset, by name (the ports number their causes differently). On
    a Pico (board "pico") a machine.reset() reads "soft", as on the ESP32, not "watchdog"."""
    try:
        code = machine.reset_cause()
    except AttributeError:
        return "unknown"
    for const_name, name in RESET_CAUSES:
        if getattr(machine, const_name, None) == code:
            if name == "watchdog" and board == "pico" and _rp2_reset_was_asked_for():
                return "soft"
            return name
    return "unknown"


def unique_id():
    try:
        return bytes(machine.unique_id())
    except AttributeError:
        return b""


def unique_id_hex():
    uid = unique_id()
    return "".join("%02x" % b for b in uid) if uid else None
