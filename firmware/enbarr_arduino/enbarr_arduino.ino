/*
 * Enbarr PWM board: an Arduino Mega 2560 driving the CS Saucer's three azimuth motor ESCs
 * (Torpedo 800) and three azimuth servos at 50 Hz, commanded by Enbarr's arduino_pwm driver
 * over USB serial (115200 8N1). Protocol and watchdog: link.h / link.c (the same code runs
 * in Enbarr's emulator). docs/hw/arduino.md has the wiring and how to flash it.
 *
 * Channels and pins (16-bit Timer3 and Timer4, fast PWM mode 14, TOP = ICRn = 39999,
 * prescaler 8: 16 MHz / 8 / 40000 = 50 Hz, 0.5 us per tick; the pin to timer map is the
 * Arduino AVR core's variants/mega/pins_arduino.h, digital_pin_to_timer_PGM):
 *
 *   channel 0  azimuth 1 motor  pin 5  OC3A (PE3)     channel 1  azimuth 1 servo  pin 6  OC4A (PH3)
 *   channel 2  azimuth 2 motor  pin 2  OC3B (PE4)     channel 3  azimuth 2 servo  pin 7  OC4B (PH4)
 *   channel 4  azimuth 3 motor  pin 3  OC3C (PE5)     channel 5  azimuth 3 servo  pin 8  OC4C (PH5)
 *
 * (azimuth k is the k-th name of the profile's azimuth_names; the Saucer: az_bow,
 * az_port_aft, az_stbd_aft). A duty of d (0.01 %) is a pulse of d * 4 ticks (6.85 % =
 * 1370 us). The output compare registers are double-buffered in mode 14 (updated at BOTTOM),
 * so a new duty never cuts a pulse.
 *
 * Safety: the outputs are neutral at reset and go neutral on their own when no valid frame
 * comes for the link's timeout (250 ms unless the host configures it); the AVR watchdog
 * (250 ms) resets a hung loop, and while the board resets the pins float and the ESCs and
 * servos get no pulses at all.
 */
#include <Arduino.h>
#include <avr/eeprom.h>
#include <avr/io.h>
#include <avr/wdt.h>

#include "link.h"

/* avr-libc manual, <avr/wdt.h>: save MCUSR and stop the watchdog before anything else runs,
 * so that a watchdog reset does not loop. */
uint8_t mcusr_mirror __attribute__((section(".noinit")));
void get_mcusr(void) __attribute__((naked, used, section(".init3")));
void get_mcusr(void)
{
    mcusr_mirror = MCUSR;
    MCUSR = 0;
    wdt_disable();
}

static enb_link board;
static uint16_t *const BOOT_COUNT_ADDR = (uint16_t *)0;  /* EEPROM word 0 */

/* The output is high for OCR + 1 ticks. link.c refuses a duty of 0 (CONFIG's duty_min is at
 * least 1): 0 * 4 - 1 would wrap to 0xFFFF, above TOP, and with no compare match the pin
 * would stay high (data sheet, 16-bit Timer/Counter, fast PWM mode). */
static uint16_t ticks(uint16_t duty)
{
    return (uint16_t)(duty * 4u - 1u);
}

static void write_outputs(void)
{
    OCR3A = ticks(enb_duty(&board, 0));
    OCR4A = ticks(enb_duty(&board, 1));
    OCR3B = ticks(enb_duty(&board, 2));
    OCR4B = ticks(enb_duty(&board, 3));
    OCR3C = ticks(enb_duty(&board, 4));
    OCR4C = ticks(enb_duty(&board, 5));
}

static void start_pwm(void)
{
    /* Stop both timers, load TOP and the neutral duties, then start them: the first pulse
     * is already neutral. */
    TCCR3B = 0;
    TCCR4B = 0;
    ICR3 = 39999u;
    ICR4 = 39999u;
    write_outputs();
    TCNT3 = 0;
    TCNT4 = 0;
    TCCR3A = _BV(COM3A1) | _BV(COM3B1) | _BV(COM3C1) | _BV(WGM31);
    TCCR4A = _BV(COM4A1) | _BV(COM4B1) | _BV(COM4C1) | _BV(WGM41);
    DDRE |= _BV(PE3) | _BV(PE4) | _BV(PE5);
    DDRH |= _BV(PH3) | _BV(PH4) | _BV(PH5);
    TCCR3B = _BV(WGM33) | _BV(WGM32) | _BV(CS31);
    TCCR4B = _BV(WGM43) | _BV(WGM42) | _BV(CS41);
}

void setup(void)
{
    uint16_t boots = (uint16_t)(eeprom_read_word(BOOT_COUNT_ADDR) + 1u);
    eeprom_update_word(BOOT_COUNT_ADDR, boots);
    enb_init(&board, millis(), boots, mcusr_mirror);
    start_pwm();
    Serial.begin(115200);
    wdt_enable(WDTO_250MS);
}

void loop(void)
{
    uint8_t buf[32];
    uint16_t n = 0;
    int room;
    wdt_reset();
    while (n < sizeof buf && Serial.available() > 0) {
        buf[n++] = (uint8_t)Serial.read();
    }
    enb_rx(&board, buf, n, millis());
    enb_tick(&board, millis());
    write_outputs();
    room = Serial.availableForWrite();
    if (room > 0) {
        n = enb_tx(&board, buf, (uint16_t)(room < (int)sizeof buf ? room : (int)sizeof buf));
        Serial.write(buf, n);
    }
}
