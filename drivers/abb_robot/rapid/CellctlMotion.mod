MODULE CellctlMotion
    !***********************************************************************************
    ! cellctl ABB driver, line protocol 1: the motion half.
    !
    ! Load into the motion task (T_ROB1). CellctlServer.mod, in a second (non-motion)
    ! task, owns the TCP socket and hands commands over through the task-global
    ! persistents below: it fills the command, then increments cellctl_cmd_seq. This
    ! task executes it, writes cellctl_result_code/_text and sets cellctl_done_seq to
    ! cellctl_cmd_seq. A STOP arrives as a change of cellctl_stop_seq; the trap StopTrap
    ! stops the robot, reports STOPPED and restarts this task's main routine, because the
    ! program pointer is blocked inside MoveL/MoveJ/EGMRunPose. STREAM starts or stops EGM's
    ! Position Stream here too (EGMStreamStart/EGMStreamStop); the stream then goes on while
    ! later commands (moves) run, until STREAM 0, a STOP or the client's going away
    ! (CellctlServer.mod raises cellctl_stop_seq, and the trap ends the stream).
    !
    ! Keep the numbers in step with drivers/abb_robot/protocol.py (a test checks them).
    !***********************************************************************************

    ! ---- task-global persistents shared with CellctlServer.mod (initial values here) ----
    PERS num cellctl_cmd_seq:=0;
    PERS num cellctl_done_seq:=0;
    PERS num cellctl_cmd_kind:=0;
    PERS robtarget cellctl_cmd_target:=[[0,0,0],[1,0,0,0],[0,0,0,0],[9E9,9E9,9E9,9E9,9E9,9E9]];
    PERS string cellctl_cmd_name:="";
    PERS num cellctl_cmd_args{3}:=[0,0,0];
    PERS num cellctl_result_code:=0;
    PERS string cellctl_result_text:="";
    PERS num cellctl_stop_seq:=0;
    PERS speeddata cellctl_speed:=[100,30,5000,1000];
    PERS zonedata cellctl_zone:=[TRUE,0,0,0,0,0,0];
    PERS tooldata cellctl_tool:=[TRUE,[[0,0,0],[1,0,0,0]],[0.001,[0,0,0.001],[1,0,0,0],0,0,0]];
    PERS wobjdata cellctl_wobj:=[FALSE,TRUE,"",[[0,0,0],[1,0,0,0]],[[0,0,0],[1,0,0,0]]];
    ! TRUE while the position stream runs (written here, read by the server task).
    PERS bool cellctl_stream_on:=FALSE;

    ! ---- command kinds (same numbers in CellctlServer.mod) ----
    CONST num CMD_MOVEL:=1;
    CONST num CMD_MOVEJ:=2;
    CONST num CMD_TOOL:=3;
    CONST num CMD_WOBJ:=4;
    CONST num CMD_EGM:=5;
    CONST num CMD_STREAM:=6;

    ! ---- result codes (abb_robot.protocol.ErrorCode; 0 = done) ----
    CONST num CELLCTL_E_OK:=0;
    CONST num CELLCTL_E_UNKNOWN_TOOL:=120;
    CONST num CELLCTL_E_UNKNOWN_WOBJ:=121;
    CONST num CELLCTL_E_REACH:=130;
    CONST num CELLCTL_E_JOINT_LIMIT:=131;
    CONST num CELLCTL_E_STOPPED:=140;
    CONST num CELLCTL_E_MOTION:=141;
    CONST num CELLCTL_E_EGM_COMM:=150;
    CONST num CELLCTL_E_EGM_SETUP:=151;
    CONST num CELLCTL_E_EGM_STATE:=152;
    CONST num CELLCTL_E_INTERNAL:=199;

    ! ---- EGM set-up: edit to match the controller's configuration ----
    ! UDPUC device (SIO: Communication > Transmission Protocol, Type UDPUC, Remote Address =
    ! the cell PC, Remote Port Number = egm_port in cellctl's [devices.robot]).
    CONST string CELLCTL_EGM_DEVICE:="UCdevice";
    ! External motion data profile (MOC: Motion > External Motion Interface Data).
    CONST string CELLCTL_EGM_PROFILE:="default";
    ! Seconds without a sensor reply before EGM stops with ERR_UDPUC_COMM (elog 41822).
    CONST num CELLCTL_EGM_COMM_TIMEOUT:=1;
    ! Low-pass filter on the references (Hz) and the largest deviation EGM accepts (mm).
    CONST num CELLCTL_EGM_LP_FILTER:=20;
    CONST num CELLCTL_EGM_MAX_DEV:=50;
    ! Position stream: an EgmRobot every CELLCTL_EGM_STREAM_RATE ms (4 = every EGM cycle).
    CONST num CELLCTL_EGM_STREAM_RATE:=4;

    VAR intnum cellctl_stop_int;
    VAR egmident cellctl_egm_id;
    VAR egmident cellctl_stream_id;
    VAR bool cellctl_egm_active:=FALSE;
    VAR num cellctl_egm_step:=0;
    VAR pose cellctl_egm_frame:=[[0,0,0],[1,0,0,0]];

    PROC main()
        CellctlInit;
        WHILE TRUE DO
            WaitUntil cellctl_cmd_seq<>cellctl_done_seq\PollRate:=0.01;
            cellctl_result_code:=CELLCTL_E_OK;
            cellctl_result_text:="";
            TEST cellctl_cmd_kind
            CASE CMD_MOVEL,CMD_MOVEJ:
                RunMove;
            CASE CMD_TOOL:
                SelectTool;
            CASE CMD_WOBJ:
                SelectWobj;
            CASE CMD_EGM:
                RunEgm;
            CASE CMD_STREAM:
                RunStream;
            DEFAULT:
                Report CELLCTL_E_INTERNAL,"unknown command kind "+NumToStr(cellctl_cmd_kind,0);
            ENDTEST
            cellctl_done_seq:=cellctl_cmd_seq;
        ENDWHILE
    ENDPROC

    PROC CellctlInit()
        ConfL\Off;
        ConfJ\Off;
        SingArea\Wrist;
        cellctl_egm_active:=FALSE;
        ResetEgm;
        ! A stream left over from before a restart is ended.
        StopStream;
        IDelete cellctl_stop_int;
        CONNECT cellctl_stop_int WITH StopTrap;
        IPers cellctl_stop_seq,cellctl_stop_int;
        ! A command left over from before a restart is not executed.
        cellctl_done_seq:=cellctl_cmd_seq;
    ENDPROC

    PROC Report(num code,string text)
        cellctl_result_code:=code;
        IF StrLen(text)>60 THEN
            cellctl_result_text:=StrPart(text,1,60);
        ELSE
            cellctl_result_text:=text;
        ENDIF
    ENDPROC

    PROC RunMove()
        VAR robtarget target;
        VAR robtarget here;
        VAR jointtarget joints;

        target:=cellctl_cmd_target;
        here:=CRobT(\Tool:=cellctl_tool\WObj:=cellctl_wobj);
        ! Keep the current arm configuration (ConfL/ConfJ are off) and external axes.
        target.robconf:=here.robconf;
        target.extax:=here.extax;
        target.rot:=NOrient(target.rot);
        ! Refuse unreachable targets before moving: ERR_OUTSIDE_REACH or ERR_ROBLIMIT.
        joints:=CalcJointT(target,cellctl_tool\WObj:=cellctl_wobj);
        IF cellctl_cmd_kind=CMD_MOVEL THEN
            MoveL target,cellctl_speed,cellctl_zone,cellctl_tool\WObj:=cellctl_wobj;
        ELSE
            MoveJ target,cellctl_speed,cellctl_zone,cellctl_tool\WObj:=cellctl_wobj;
        ENDIF
        Report CELLCTL_E_OK,"";
    ERROR
        IF ERRNO=ERR_OUTSIDE_REACH THEN
            Report CELLCTL_E_REACH,"target outside the robot's reach";
        ELSEIF ERRNO=ERR_ROBLIMIT THEN
            Report CELLCTL_E_JOINT_LIMIT,"target needs an axis beyond its limit";
        ELSE
            Report CELLCTL_E_MOTION,"motion error "+NumToStr(ERRNO,0);
        ENDIF
        RETURN;
    ENDPROC

    PROC SelectTool()
        VAR tooldata found;

        GetDataVal cellctl_cmd_name,found;
        cellctl_tool:=found;
        Report CELLCTL_E_OK,"";
    ERROR
        Report CELLCTL_E_UNKNOWN_TOOL,"no tooldata "+cellctl_cmd_name;
        RETURN;
    ENDPROC

    PROC SelectWobj()
        VAR wobjdata found;

        GetDataVal cellctl_cmd_name,found;
        cellctl_wobj:=found;
        Report CELLCTL_E_OK,"";
    ERROR
        Report CELLCTL_E_UNKNOWN_WOBJ,"no wobjdata "+cellctl_cmd_name;
        RETURN;
    ENDPROC

    PROC RunEgm()
        ! Pose mode, references and feedback in the current tool and work object (the same
        ! frame as MoveL), until every axis stays within its band for CondTime seconds.
        VAR egm_minmax band_lin;
        VAR egm_minmax band_rot;

        band_lin:=[-cellctl_cmd_args{1},cellctl_cmd_args{1}];
        band_rot:=[-cellctl_cmd_args{2},cellctl_cmd_args{2}];
        cellctl_egm_step:=1;
        EGMGetId cellctl_egm_id;
        EGMSetupUC ROB_1,cellctl_egm_id,CELLCTL_EGM_PROFILE,CELLCTL_EGM_DEVICE\Pose\CommTimeout:=CELLCTL_EGM_COMM_TIMEOUT;
        EGMActPose cellctl_egm_id\Tool:=cellctl_tool\WObj:=cellctl_wobj,cellctl_egm_frame,EGM_FRAME_WOBJ,
            cellctl_egm_frame,EGM_FRAME_WOBJ\X:=band_lin\Y:=band_lin\Z:=band_lin
            \Rx:=band_rot\Ry:=band_rot\Rz:=band_rot\LpFilter:=CELLCTL_EGM_LP_FILTER\SampleRate:=4
            \MaxPosDeviation:=CELLCTL_EGM_MAX_DEV;
        cellctl_egm_step:=2;
        cellctl_egm_active:=TRUE;
        EGMRunPose cellctl_egm_id,EGM_STOP_HOLD\X\Y\Z\Rx\Ry\Rz\CondTime:=cellctl_cmd_args{3}\RampInTime:=0.05;
        cellctl_egm_active:=FALSE;
        ResetEgm;
        Report CELLCTL_E_OK,"";
    ERROR
        cellctl_egm_active:=FALSE;
        IF ERRNO=ERR_UDPUC_COMM THEN
            Report CELLCTL_E_EGM_COMM,"no data from the sensor (41822)";
        ELSEIF cellctl_egm_step<2 THEN
            Report CELLCTL_E_EGM_SETUP,"EGM setup failed, error "+NumToStr(ERRNO,0);
        ELSE
            Report CELLCTL_E_EGM_STATE,"EGM error "+NumToStr(ERRNO,0);
        ENDIF
        ResetEgm;
        RETURN;
    ENDPROC

    PROC ResetEgm()
        EGMReset cellctl_egm_id;
    ERROR
        ! Nothing registered under this id: nothing to reset.
        RETURN;
    ENDPROC

    PROC RunStream()
        ! STREAM 1: (re)start the Position Stream, STREAM 0: stop it. The controller then sends
        ! an EgmRobot (feedback: the TCP in the current tool and work object, as EGMActPose
        ! sets the frames; header.tm in ms) every CELLCTL_EGM_STREAM_RATE ms to the UdpUc
        ! device's remote port, while RAPID moves run; the sensor sends nothing back.
        IF cellctl_stream_on StopStream;
        IF cellctl_cmd_args{1}=0 THEN
            Report CELLCTL_E_OK,"";
            RETURN;
        ENDIF
        EGMGetId cellctl_stream_id;
        EGMSetupUC ROB_1,cellctl_stream_id,CELLCTL_EGM_PROFILE,CELLCTL_EGM_DEVICE\Pose;
        EGMActPose cellctl_stream_id\Tool:=cellctl_tool\WObj:=cellctl_wobj,cellctl_egm_frame,EGM_FRAME_WOBJ,
            cellctl_egm_frame,EGM_FRAME_WOBJ;
        EGMStreamStart cellctl_stream_id\SampleRate:=CELLCTL_EGM_STREAM_RATE;
        cellctl_stream_on:=TRUE;
        Report CELLCTL_E_OK,"";
    ERROR
        Report CELLCTL_E_EGM_SETUP,"EGM stream setup failed, error "+NumToStr(ERRNO,0);
        StopStream;
        RETURN;
    ENDPROC

    PROC StopStream()
        ! End the position stream and free its EGM identity (an error: nothing streamed).
        cellctl_stream_on:=FALSE;
        EGMStreamStop cellctl_stream_id;
        EGMReset cellctl_stream_id;
    ERROR
        TRYNEXT;
    ENDPROC

    TRAP StopTrap
        ! A STOP, or the client's going away, ends the position stream first.
        IF cellctl_stream_on StopStream;
        IF cellctl_cmd_seq=cellctl_done_seq THEN
            ! Nothing running: nothing to stop.
            RETURN;
        ENDIF
        IF cellctl_egm_active THEN
            EGMStop cellctl_egm_id,EGM_STOP_HOLD;
            cellctl_egm_active:=FALSE;
        ENDIF
        StopMove;
        ClearPath;
        StartMove;
        Report CELLCTL_E_STOPPED,"stopped on request";
        cellctl_done_seq:=cellctl_cmd_seq;
        ! The program pointer sits in the interrupted move: start over from main.
        ExitCycle;
    ENDTRAP
ENDMODULE
