"""One conformance suite, run through every front (in-process link, TCP, pty).

Each test sends raw bytes and checks raw bytes; time moves only when a test advances the
simulator's manual clock.
"""

from __future__ import annotations

from engine_expect import in_position_after, lagged, move, references, soft_limit_stop
from sim_fronts import WAIT, Front

from galil.models import get_model
from galil.predict.checks import quantise_accel

PROGRAM = (
    b'#A\rMG "hello"\rWT 100\rMG "bye"\rEN\r#LOOP\rn=0\r#L2\rn=n+1\rJP #L2,n<5\rMG "n=",n\rEN\r\\'
)


def tc1(front: Front) -> bytes:
    return front.ask(b"TC1")


def test_identity(front: Front) -> None:
    assert front.ask(b"\x12\x16") == b"DMC4040 Rev 1.2f-sim\r\n:"


def test_ack_and_reject(front: Front) -> None:
    assert front.ask(b"SP 1000") == b":"
    assert front.ask(b"bg") == b"?"
    assert tc1(front) == b" 1 Unrecognized command\r\n:"
    assert front.ask(b"TC") == b" 0\r\n:"  # reading TC cleared it
    assert front.ask(b"XX") == b"?"


def test_compound_lines_answer_each_command(front: Front) -> None:
    assert front.ask(b"a=1;b=2") == b"::"
    assert front.ask(b"a=5;MG a") == b": 5.0000\r\n:"
    assert front.ask(b"a=1;pr 1;b=3") == b":?:"
    assert front.ask(b"MG a+b*2") == b" 8.0000\r\n:"  # left to right: (1+3)*2


def test_query_formats(front: Front) -> None:
    assert front.ask(b"TPA") == b" 0\r\n:"
    assert front.ask(b"TP") == b" 0, 0, 0, 0\r\n:"
    assert front.ask(b"PR 1000,,-200") == b":"
    assert front.ask(b"PR ?,?,?") == b" 1000, 0,-200\r\n:"
    assert front.ask(b"PRB=500;PR ?,?") == b": 1000, 500\r\n:"
    assert front.ask(b"LZ 0;PR ?") == b": 0000001000\r\n:"
    assert front.ask(b"PF 4.1;PR ?") == b": 1000.0\r\n:"
    assert front.ask(b"LZ 1;VF 3.2;MG 2.5") == b":: 2.50\r\n:"
    assert front.ask(b'MG "x=", 7 {F3.1}') == b"x= 007.0\r\n:"
    assert front.ask(b"AC 150000;AC ?") == b": 149504\r\n:"
    assert front.ask(b"QZ") == b" 4, 52, 26, 36\r\n:"


def test_mg_formats_override_vf_and_lz_for_their_own_argument(front: Front) -> None:
    # DMC-4103 reference, MG: "Formatters can be placed after each argument ... to modify how
    # it is printed"; {Fm.n} keeps leading zeros, {Zm.n} suppresses them (decision 0032).
    assert front.ask(b"VF 4.0;LZ 0") == b"::"
    assert front.ask(b"MG 123456.25") == b" 9999\r\n:"  # VF overflow: nines
    assert front.ask(b"MG 123456.25{Z10.4},-7{Z10.4}") == b" 123456.2500-7.0000\r\n:"
    assert front.ask(b"MG 4.1{F5.2}") == b" 00004.10\r\n:"  # (DMC-1700 manual)
    assert front.ask(b"MG 999999.999{F5.2}") == b" 99999.99\r\n:"  # (DMC-1700 manual)
    assert front.ask(b'MG "total",1234.5322{F4.2}') == b"total 1234.53\r\n:"
    assert front.ask(b"MG 1{F3.1},2") == b" 001.0 0002\r\n:"  # the next one is in VF again
    assert front.ask(b"VF -4.0;MG _VF{Z10.4},_PF{Z10.4}") == b":-4.0000 10.0000\r\n:"
    assert front.ask(b"VF 10.4;LZ 1") == b"::"


def test_variables(front: Front) -> None:
    assert front.ask(b"speed=1234.5") == b":"
    assert front.ask(b"speed=") == b" 1234.5000\r\n:"
    assert front.ask(b"MG speed") == b" 1234.5000\r\n:"
    assert front.ask(b"MG nothere") == b"?"
    assert tc1(front).startswith(b" 1 ")


def test_number_out_of_range(front: Front) -> None:
    assert front.ask(b"SP -5") == b"?"
    assert tc1(front) == b" 6 Number out of range\r\n:"
    assert front.ask(b"IT 2") == b"?"
    assert front.ask(b"SP ?") == b" 25000\r\n:"  # unchanged


def test_refused_command_changes_nothing(front: Front) -> None:
    assert front.ask(b"PR 100,200") == b":"
    assert front.ask(b"PR 5,nothere") == b"?"
    assert front.ask(b"PR ?,?") == b" 100, 200\r\n:"
    assert front.ask(b"MO B;BG AB") == b":?"
    assert tc1(front) == b" 20 Begin not valid with motor off\r\n:"
    assert front.ask(b"MG _BGA") == b" 0.0000\r\n:"


def test_an_unknown_axis_is_refused_with_tc_4(front: Front) -> None:
    for line in (b"TP Q", b"BG AQ", b"SP Q=5", b"MG _TPQ"):
        assert front.ask(line) == b"?"
        assert tc1(front) == b" 4 Operand error\r\n:"


def test_motion_codes(front: Front) -> None:
    assert front.ask(b"PR 100000;SP 10000;BG A") == b":::"
    assert front.ask(b"BG A") == b"?"
    assert tc1(front) == b" 21 Begin not valid while running\r\n:"
    assert front.ask(b"PR 5") == b"?"
    assert tc1(front) == b" 7 Command not valid while running\r\n:"
    assert front.ask(b"DC 100000") == b"?"
    assert front.ask(b"JG 500") == b"?"
    assert tc1(front) == b" 13 JG only valid when running in jog mode\r\n:"
    assert front.ask(b"IP -10") == b"?"
    assert tc1(front).startswith(b" 16 IP incorrect sign")
    assert front.ask(b"MO A") == b"?"
    assert front.ask(b"ST A") == b":"
    front.advance(2.0)
    assert front.ask(b"MG _BGA;SC A") == b" 0.0000\r\n: 4\r\n:"


def unsolicited(front: Front, expected: bytes) -> bytes:
    """Read a program's messages (the message handle on TCP) until ``expected``'s length."""
    got = b""
    while len(got) < len(expected):
        chunk = front.messages(WAIT)
        assert chunk, got
        got += chunk
    return got


def test_am_mc_and_wt_from_the_host_are_refused_with_tc_2(front: Front) -> None:
    # DMC-4103 reference: AM, MC and WT are "Not Valid in terminal" (decision 0044).
    assert front.ask(b"PR 1000;SP 10000;BG A") == b":::"
    for line in (b"AM A", b"AM", b"MC A", b"WT 100", b"AM S"):
        assert front.ask(line) == b"?"
        assert tc1(front) == b" 2 Command only valid from program\r\n:"
    assert front.ask(b"MG _BGA") == b" 1.0000\r\n:"  # refused at once, the move goes on


def test_am_holds_a_program_thread_until_the_profile_is_done(front: Front) -> None:
    assert front.ask(b"PR 1000;SP 10000;BG A") == b":::"
    front.write(b"DL\r#W\rAM A\rMG 42\rEN\r\\")
    assert front.read_terminators(2) == b"::"
    assert front.ask(b"XQ #W") == b":"
    front.advance(0.05)
    assert front.messages(0.05) == b""  # MG 42 waits behind the trippoint
    front.advance(1.0)
    assert unsolicited(front, b" 42.0000\r\n") == b" 42.0000\r\n"
    assert front.ask(b"RPA;MG _BGA") == b" 1000\r\n: 0.0000\r\n:"


def test_mc_waits_for_the_motor_after_am(front: Front) -> None:
    front.controller.set_servo_lag(0.05)
    front.write(b"DL\r#W\rAM A;MG TIME;MG _TEA;MC A;MG TIME\rEN\r\\")
    assert front.read_terminators(2) == b"::"
    assert front.ask(b"PR 2000;SP 20000;AC 1000000;DC 1000000;BG A;XQ #W") == b"::::::"
    assert front.messages(0.05) == b""
    front.advance(1.0)
    accel = quantise_accel(1000000, get_model("DMC-4040"))  # AC/DC as the controller stores them
    refs = references(move(2000, 20000, accel, accel))
    te = refs[-1] - lagged(refs, 0.05)[-1]  # the motor lags the reference when AM releases
    t_mc = in_position_after(refs, 0.05)
    assert te > 0
    expected = f" {len(refs)}.0000\r\n {te}.0000\r\n {t_mc}.0000\r\n".encode()
    assert unsolicited(front, expected) == expected
    assert front.ask(b"TEA;TPA") == b" 0\r\n: 2000\r\n:"


def test_time_and_mg(front: Front) -> None:
    front.advance(1.0)
    assert front.ask(b"MG TIME") == b" 1024.0000\r\n:"
    assert front.ask(b'MG "pos", _TPA, "!"') == b"pos 0.0000!\r\n:"
    assert front.ask(b'MG "no newline" {N}') == b"no newline:"


def test_jog_speed_and_tv(front: Front) -> None:
    assert front.ask(b"JG 5000;BG A") == b"::"
    front.advance(1.0)
    assert front.ask(b"TVA") == b" 5000\r\n:"
    assert front.ask(b"JG -3000") == b":"
    front.advance(1.0)
    assert front.ask(b"TVA") == b"-3000\r\n:"
    assert front.ask(b"AB") == b":"
    assert front.ask(b"SC A;MG _BGA") == b" 7\r\n: 0.0000\r\n:"


def test_limit_switch_stops_and_refuses_begin(front: Front) -> None:
    assert front.ask(b"JG 5000;BG A") == b"::"
    front.advance(0.5)
    front.controller.set_limit_switch("A", "forward", True)
    front.advance(1.0)
    assert front.ask(b"MG _BGA;SC A;TS A") == b" 0.0000\r\n: 2\r\n: 7\r\n:"
    assert front.ask(b"BG A") == b"?"
    assert tc1(front) == b" 22 Begin not possible due to limit switch\r\n:"
    assert front.ask(b"JG -5000;BG A") == b"::"  # away from the switch is fine


def test_soft_limit(front: Front) -> None:
    assert front.ask(b"FL 500;PR 2000;BG A") == b":::"
    front.advance(2.0)
    assert front.ask(b"SC A") == b" 2\r\n:"
    assert front.ask(b"RPA") == f" {soft_limit_stop(2000, 500)}\r\n:".encode()
    assert front.ask(b"PR 10;BG A") == b":?"
    assert front.ask(b"PR -10;BG A") == b"::"


def test_contour_buffer_and_wc(front: Front) -> None:
    assert front.ask(b"CM A;DT 3") == b"::"
    assert front.ask(b"MG _CM") == b" 511.0000\r\n:"
    assert front.ask(b"CD 80;CD 80;CD 80") == b":::"
    assert front.ask(b"MG _CM") == b" 509.0000\r\n:"
    front.write(b"WC\r")
    assert front.quiet() == b""
    front.advance(0.1)  # 3 segments of 8 samples: all run
    assert front.read_terminators(1) == b":"
    assert front.ask(b"CD 40000") == b"?"
    assert tc1(front) == b" 41 Contouring record range error\r\n:"
    assert front.ask(b"CD 0=0;RPA") == b": 240\r\n:"
    front.advance(0.01)
    assert front.ask(b"SC A") == b" 51\r\n:"


def expect(front: Front, line: bytes, reply: bytes, message: bytes, wait: float = 0.0) -> None:
    """Send ``line``: its reply on the command stream, ``message`` as unsolicited output
    within ``wait`` simulated seconds."""
    if front.name == "tcp":
        assert front.ask(line) == reply
        front.advance(wait)
        got = b""
        while len(got) < len(message):
            chunk = front.messages(5.0)
            assert chunk, got
            got += chunk
        assert got == message
    else:  # serial-like fronts interleave messages with replies
        got = front.ask(line)
        front.advance(wait)
        while len(got) < len(reply) + len(message):
            chunk = front.read_some(5.0)
            assert chunk, got
            got += chunk
        assert got == reply + message


def test_program_messages_and_cw(front: Front) -> None:
    front.write(b"DL\r" + PROGRAM)
    assert front.read_terminators(2) == b"::"
    expect(front, b"XQ #A", b":", b"hello\r\n")
    front.advance(0.2)
    assert front.messages(5.0) == b"bye\r\n"
    mark = bytes(b | 0x80 for b in b"n= 5.0000\r\n")
    expect(front, b"CW 1;XQ #LOOP", b"::", mark, wait=0.01)
    front.controller.emit_message("hook")
    assert front.messages(5.0) == bytes(b | 0x80 for b in b"hook\r\n")
    up = front.ask(b"UL")
    assert up.startswith(b"#A\r\nMG")
    assert up.endswith(b"\x1a:")
    assert front.ask(b"MG _XQ0") == b"-1.0000\r\n:"


def test_echo(front: Front) -> None:
    assert front.ask(b"EO 1") == b":"
    front.write(b"TPA\r")
    assert front.read_terminators(1) == b"TPA\r 0\r\n:"


def test_data_record(front: Front) -> None:
    front.write(b"QR\r")
    data = b""
    while len(data) < 82 + 4 * 36 + 1:
        chunk = front.read_some(5.0)
        assert chunk, data
        data += chunk
    assert len(data) == 82 + 4 * 36 + 1
    assert data.endswith(b":")
    assert int.from_bytes(data[2:4], "little") == 82 + 4 * 36
