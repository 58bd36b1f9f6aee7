"""flight_story: what a failed SITL flight's test prints (companion_firmware.truth_harness)."""

from companion_firmware.truth_harness import flight_story


def test_the_story_lists_events_failed_requests_status_changes_and_the_firmware_logs_end(tmp_path):
    run = tmp_path / "run"
    run.mkdir()
    (run / "events.csv").write_text(
        "time_s,kind,phase,detail\n1.0,phase,takeoff,takeoff\n21.0,abort,takeoff,takeoff did not reach 2.5 m in time\n"
    )
    (run / "requests.csv").write_text(
        "time_s,seq,id,kind,ok,error,permanent\n1.1,5,2,takeoff,1,,0\n21.1,9,3,hold,0,no answer within 5.0 s,0\n"
    )
    (run / "ap_status.csv").write_text(
        "time_s,seq,armed,mode,landed,healthy,battery_pct,payload_released\n"
        "1.0,1,1,takeoff,on_ground,1,100.0,0\n2.0,2,1,takeoff,on_ground,1,99.0,0\n3.0,3,1,takeoff,taking_off,1,99.0,0\n"
    )
    (run / "ap_statustext.csv").write_text('time_s,seq,severity,text\n4.0,7,4,"Failsafe: ""x"""\n')
    fw = tmp_path / "px4.log"
    fw.write_text("".join(f"line {i}\n" for i in range(50)))
    text = flight_story(run, fw, tail_lines=3)
    assert "  21.0 takeoff abort takeoff did not reach 2.5 m in time" in text
    assert "  1.1 #2 takeoff ok" in text and "  21.1 #3 hold FAILED no answer within 5.0 s" in text
    # one line a change, not a row: the battery moving is no change
    assert "ap_status.csv (3 rows, last at 3.0), changes:" in text
    assert text.count("mode=takeoff") == 2 and "landed=taking_off" in text
    assert '  4.0 [4] Failsafe: "x"' in text
    assert "px4.log, last 3 of 50 lines:\n  line 47\n  line 48\n  line 49" in text
    # ap_position.csv is missing: named, and the rest still told
    assert "ap_position.csv: not readable" in text


def test_the_story_of_an_empty_folder_names_every_missing_file(tmp_path):
    text = flight_story(tmp_path, tmp_path / "absent.log")
    for name in ("events.csv", "requests.csv", "ap_status.csv", "ap_position.csv", "ap_statustext.csv", "absent.log"):
        assert f"{name}: not readable" in text
